"""The app's HTTP server: the page, and a small JSON API the page calls.

    GET  /                                     the page (static/index.html)
    POST /api/session                          → {"session": id}
    POST /api/upload?session=&kind=&name=      body: the file → {"width", "height", "frames"?}
    POST /api/mask?session=&kind=              body: {"points", "box", "exclude"} → {"preview": url}
    POST /api/run?session=                     body: the settings → {"state": "queued"}
    GET  /api/status?session=                  → {"state", "stage", "progress", "source"?, "video"?, "message"?}
    GET  /api/file?session=&name=              a file of the session (previews, result.mp4)

Bad input is a 400 with ``{"error": "…"}`` (the page shows it); the server
keeps serving. Requests are served on threads of their own, runs on the
worker of :class:`~marionette.app.jobs.Sessions`.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from ..address import check_address
from ..errors import InputError
from ..options import checked, parse_background, parse_focal, parse_parts
from ..prior import MOTION_FRAMES
from ..render.camera_path import CAMERA_MOVES
from ..segment import Prompt
from .jobs import Sessions, Settings

__all__ = ["AppServer", "serve_app"]

#: Largest upload taken (bytes).
MAX_UPLOAD = 512 * 2**20
#: Files of a session the page may fetch.
_FILE_NAME = re.compile(r"(source|target)(_mask)?\.png|result\.mp4")
_TYPES = {".png": "image/png", ".mp4": "video/mp4", ".html": "text/html; charset=utf-8"}


def _point(value) -> tuple[float, float]:
    if not (isinstance(value, list) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value)):
        raise InputError(f"a point must be [x, y], got {value!r}")
    return float(value[0]), float(value[1])


def _prompt(body: dict | None) -> Prompt | None:
    """A prompt from the page's ``{"points": [[x, y]…], "box": [x0, y0, x1, y1] | null, "exclude": […]}``."""
    if not body:
        return None
    box = body.get("box")
    if box is not None and not (isinstance(box, list) and len(box) == 4
                                and all(isinstance(v, (int, float)) for v in box)):
        raise InputError(f"a box must be [x0, y0, x1, y1], got {box!r}")
    prompt = Prompt(tuple(_point(p) for p in body.get("points") or ()), None if box is None else tuple(box),
                    tuple(_point(p) for p in body.get("exclude") or ()))
    return prompt if prompt or prompt.exclude else None


def _settings(body: dict) -> Settings:
    """Run settings from the page, checked as the command line checks them."""
    speed = float(body.get("speed", 1.0))
    if not (math.isfinite(speed) and 0.05 <= speed <= 20):
        raise InputError(f"speed must be within 0.05..20, got {speed}")
    frames = body.get("frames")
    if frames is not None:
        frames = int(frames)
        if not 2 <= frames <= 2000:
            raise InputError(f"frames must be within 2..2000, got {frames}")
    camera = body.get("camera", "static")
    if camera not in CAMERA_MOVES:
        raise InputError(f"camera must be one of {', '.join(CAMERA_MOVES)}, got {camera!r}")
    motion = body.get("motion", "filmed")
    if motion not in MOTION_FRAMES:
        raise InputError(f"motion must be one of {', '.join(MOTION_FRAMES)}, got {motion!r}")
    background = body.get("background", "1,1,1")
    if background != "scene":
        background = checked("background", parse_background, background)
    return Settings(speed, frames, camera, motion, background, _prompt(body.get("source")),
                    _prompt(body.get("target")), checked("parts", parse_parts, body.get("parts", 1)),
                    checked("focal", parse_focal, body.get("focal")))


class _Handler(BaseHTTPRequestHandler):
    sessions: Sessions  # set on the subclass made per server
    server_version = "marionette-app"

    def log_message(self, format: str, *args) -> None:  # noqa: A002 - quiet: the command prints what matters
        pass

    def _send(self, status: int, body: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, payload: dict, status: int = HTTPStatus.OK) -> None:
        self._send(status, json.dumps(payload).encode(), "application/json")

    def _query(self) -> dict[str, str]:
        return {k: v[0] for k, v in parse_qs(urlparse(self.path).query).items()}

    def _body(self) -> bytes:
        length = int(self.headers.get("Content-Length") or 0)
        if length > MAX_UPLOAD:
            raise InputError(f"upload too large ({length / 2**20:.0f} MB; at most {MAX_UPLOAD // 2**20} MB)")
        return self.rfile.read(length)

    def _handle(self, action) -> None:
        try:
            action()
        except InputError as e:
            self._json({"error": str(e).splitlines()[0]}, HTTPStatus.BAD_REQUEST)
        except (ValueError, TypeError, KeyError, json.JSONDecodeError) as e:
            self._json({"error": f"bad request: {e}"}, HTTPStatus.BAD_REQUEST)

    def do_GET(self) -> None:  # noqa: N802 - the http.server name
        route = urlparse(self.path).path
        if route in ("/", "/index.html"):
            page = resources.files("marionette.app").joinpath("static/index.html").read_bytes()
            self._send(HTTPStatus.OK, page, _TYPES[".html"])
        elif route == "/api/status":
            self._handle(lambda: self._json(dict(self.sessions.get(self._query()["session"]).status)))
        elif route == "/api/file":
            self._handle(self._file)
        else:
            self._json({"error": f"no page {route}"}, HTTPStatus.NOT_FOUND)

    def _file(self) -> None:
        query = self._query()
        name = query.get("name", "")
        if not _FILE_NAME.fullmatch(name):
            raise InputError(f"no file {name!r}")
        path = self.sessions.get(query["session"]).folder / name
        if not path.is_file():
            self._json({"error": f"{name} is not there (yet)"}, HTTPStatus.NOT_FOUND)
            return
        self._send(HTTPStatus.OK, path.read_bytes(), _TYPES[path.suffix])

    def do_POST(self) -> None:  # noqa: N802 - the http.server name
        route = urlparse(self.path).path
        actions = {"/api/session": self._new_session, "/api/upload": self._upload, "/api/mask": self._mask,
                   "/api/run": self._run}
        if route not in actions:
            self._json({"error": f"no action {route}"}, HTTPStatus.NOT_FOUND)
            return
        self._handle(actions[route])

    def _new_session(self) -> None:
        self._json({"session": self.sessions.new()})

    def _upload(self) -> None:
        query = self._query()
        session = self.sessions.get(query["session"])
        info = session.upload(query.get("kind", ""), query.get("name", ""), self._body())
        self._json({**info, "preview": f"/api/file?session={query['session']}&name={query['kind']}.png"})

    def _mask(self) -> None:
        query = self._query()
        kind = query.get("kind", "")
        if kind not in ("source", "target"):
            raise InputError(f"unknown kind {kind!r}")
        session = self.sessions.get(query["session"])
        if getattr(session, kind) is None:
            raise InputError(f"upload the {'clip' if kind == 'source' else 'photo'} first")
        path = session.mask_preview(kind, _prompt(json.loads(self._body() or b"{}")))
        self._json({"preview": f"/api/file?session={query['session']}&name={path.name}"})

    def _run(self) -> None:
        query = self._query()
        self.sessions.submit(query["session"], _settings(json.loads(self._body() or b"{}")))
        self._json({"state": "queued"})


class AppServer:
    """A running app: its ``url``; :meth:`stop` shuts it down."""

    def __init__(self, host: str, port: int, workdir: Path, temporary: bool = False) -> None:
        self.sessions = Sessions(workdir)
        self._temporary = temporary
        handler = type("Handler", (_Handler,), {"sessions": self.sessions})
        self._server = ThreadingHTTPServer((host, port), handler)
        self._server.daemon_threads = True
        # shutdown() waits for the serving loop's next poll: 0.5 s by default, at every stop.
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="marionette-app", daemon=True)
        self._thread.start()
        bound_host, bound_port = self._server.server_address[:2]
        self.url = f"http://{bound_host}:{bound_port}"

    def stop(self) -> None:
        """Stop serving; a work folder the app made itself is removed with everything in it."""
        self._server.shutdown()
        self._server.server_close()
        self.sessions.close(remove=self._temporary)


def serve_app(host: str = "127.0.0.1", port: int = 8765, workdir: str | Path | None = None) -> AppServer:
    """Start the app on ``host:port`` (0: any free port; one in use is an error) and return at once; work
    files under ``workdir`` (default: a fresh temporary folder, removed when the app stops)."""
    import tempfile

    port = int(port)
    check_address(host, port)  # before the work folder is made
    root = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="marionette-app-"))
    try:
        return AppServer(host, port, root, temporary=workdir is None)
    except OSError as e:
        if workdir is None:
            shutil.rmtree(root, ignore_errors=True)
        raise InputError(f"cannot listen on {host}:{port} ({e.strerror or e})") from None
