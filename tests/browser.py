"""Headless Chromium driven through the DevTools protocol, for the web page tests."""

import base64
import contextlib
import itertools
import json
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import cv2
import numpy as np
import websockets.sync.client

CHROMIUM = Path("/usr/bin/chromium")


@contextlib.contextmanager
def browser(url: str):
    """Headless Chromium (software WebGL) showing ``url`` at 800x600; yields
    ``(wait, call)``: ``wait(predicate)`` takes screenshots through the DevTools
    protocol until ``predicate(image)`` holds and returns that RGB image (the
    last one after 60 s); ``call(method, **params)`` sends any DevTools command
    and returns its result. Polling, rather than ``--screenshot``, because Chromium's
    virtual time does not wait for websocket messages: on a busy machine a
    one-shot screenshot is often taken before the scene has arrived."""
    # Chromium's helper processes may still write to the profile after the browser exits.
    with tempfile.TemporaryDirectory(ignore_cleanup_errors=True) as profile:
        process = subprocess.Popen(
            [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
             "--disable-quic", "--no-first-run", "--disable-background-networking",
             "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}",
             "--window-size=800,600", "--remote-debugging-port=0", url],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        try:
            port_file, deadline = Path(profile) / "DevToolsActivePort", time.monotonic() + 60
            while len(lines := (port_file.read_text().split() if port_file.exists() else [])) < 2:
                assert time.monotonic() < deadline and process.poll() is None, "Chromium did not start"
                time.sleep(0.1)
            with urllib.request.urlopen(f"http://127.0.0.1:{lines[0]}/json/list", timeout=10) as r:
                page = next(t for t in json.load(r) if t["type"] == "page")
            with websockets.sync.client.connect(page["webSocketDebuggerUrl"], max_size=None) as devtools:
                ids = itertools.count(1)

                def call(method: str, **params) -> dict:
                    key = next(ids)
                    devtools.send(json.dumps({"id": key, "method": method, "params": params}))
                    while (reply := json.loads(devtools.recv())).get("id") != key:
                        pass  # events
                    if "error" in reply:
                        raise RuntimeError(f"{method}: {reply['error']}")
                    return reply["result"]

                def wait(predicate) -> np.ndarray:
                    deadline = time.monotonic() + 60
                    while True:
                        reply = {"result": call("Page.captureScreenshot")}
                        png = np.frombuffer(base64.b64decode(reply["result"]["data"]), np.uint8)
                        image = cv2.cvtColor(cv2.imdecode(png, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
                        if predicate(image) or time.monotonic() > deadline:
                            return image
                        time.sleep(0.25)
                yield wait, call
        finally:
            process.terminate()
            process.wait(timeout=30)




class Page:
    """The page of a :func:`browser`, driven as a user drives it (``call`` is the DevTools callable)."""

    def __init__(self, call) -> None:
        self.call = call

    def evaluate(self, expression: str):
        """The value of a JavaScript expression (promises awaited)."""
        reply = self.call("Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True)
        return reply["result"].get("value")

    def until(self, expression: str, timeout: float = 240) -> None:
        """Wait until the expression is truthy (AssertionError after ``timeout`` seconds)."""
        deadline = time.monotonic() + timeout
        while not self.evaluate(expression):
            assert time.monotonic() < deadline, f"timed out waiting for {expression}"
            time.sleep(0.25)

    def upload(self, input_id: str, path: Path) -> None:
        """Pick ``path`` in the file input ``#input_id``."""
        root = self.call("DOM.getDocument")["root"]["nodeId"]
        node = self.call("DOM.querySelector", nodeId=root, selector=f"#{input_id}")["nodeId"]
        self.call("DOM.setFileInputFiles", nodeId=node, files=[str(path)])

    def click_image(self, image_id: str, x: float, y: float) -> None:
        """A mouse click on pixel (x, y) of the image ``#image_id`` (its own pixels, wherever it is shown)."""
        left, top, width, height = self.evaluate(
            f"(() => {{ const i = document.getElementById('{image_id}'); const r = i.getBoundingClientRect();"
            " return [r.left, r.top, r.width / i.naturalWidth, r.height / i.naturalHeight]; })()")
        for kind in ("mousePressed", "mouseReleased"):
            self.call("Input.dispatchMouseEvent", type=kind, x=left + (x + 0.5) * width, y=top + (y + 0.5) * height,
                      button="left", clickCount=1)
