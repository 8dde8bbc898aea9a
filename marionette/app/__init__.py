"""A local web app (``marionette app``): upload a clip and a photo, click the objects, get the video.

:func:`serve_app` starts the server and returns at once (tests,
notebooks); :func:`run_app` is the blocking loop of the command. The page
and its API are in :mod:`.server`, the work in :mod:`.jobs`.
"""

from .server import AppServer, serve_app

__all__ = ["AppServer", "serve_app", "run_app"]


def run_app(host: str = "127.0.0.1", port: int = 8765, workdir=None, announce=None) -> None:
    """Serve until interrupted, then stop and let the KeyboardInterrupt through; ``announce(server)`` once
    serving (default: print the address)."""
    import threading

    server = serve_app(host, port, workdir)
    try:
        (announce or (lambda s: print(f"app at {s.url} (Ctrl-C to stop)")))(server)
        threading.Event().wait()
    finally:
        server.stop()
