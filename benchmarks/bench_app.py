"""The local web app (issue 18): the time from upload to finished video, and a picture of the page.

A 50-frame synthetic clip (``make_scene("outofplane")``, 320x240) and a 512x512 photo of a synthetic
vase are uploaded to a fresh ``serve_app`` through its HTTP API, the photo's object is clicked, and a run
is started; the time is measured from the start of the upload to the video being ready (median of
``--runs``). Then the same is done in headless Chromium (when
``/usr/bin/chromium`` exists) and the page is captured to ``docs/images/app.png``. Writes
``docs/benchmarks/app.md``.

    flock /tmp/marionette-bench.lock python benchmarks/bench_app.py [--runs 3]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import cv2

from marionette.app import serve_app
from marionette.io import write_image, write_video
from marionette.synthetic import make_scene, render_object_image

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "app.md"
FRAMES = 50


def post(url: str, body: bytes | dict) -> dict:
    data = body if isinstance(body, bytes) else json.dumps(body).encode()
    with urllib.request.urlopen(urllib.request.Request(url, data=data, method="POST"), timeout=120) as reply:
        return json.loads(reply.read())


def one_run(app, clip: Path, photo: Path) -> tuple[float, dict]:
    """Seconds from the upload's start to the finished video, and the final status."""
    start = time.perf_counter()
    session = post(app.url + "/api/session", b"")["session"]
    post(f"{app.url}/api/upload?session={session}&kind=source&name=clip.mp4", clip.read_bytes())
    post(f"{app.url}/api/upload?session={session}&kind=target&name=photo.png", photo.read_bytes())
    post(f"{app.url}/api/run?session={session}", {"target": {"points": [[256, 256]]}})
    while True:
        with urllib.request.urlopen(f"{app.url}/api/status?session={session}", timeout=30) as reply:
            status = json.loads(reply.read())
        if status["state"] in ("done", "error"):
            break
        time.sleep(0.1)
    if status["state"] != "done":
        raise SystemExit(f"the run failed: {status}")
    return time.perf_counter() - start, status


def screenshot(app, clip: Path, photo: Path) -> Path | None:
    """The page after a run in headless Chromium, saved to docs/images/app.png."""
    sys.path.insert(0, str(ROOT / "tests"))
    from browser import CHROMIUM, Page, browser

    if not CHROMIUM.exists():
        return None
    with browser(app.url) as (wait, call):
        page = Page(call)
        page.until("typeof session === 'string'")
        for kind, path in (("source", clip), ("target", photo)):
            page.upload(f"{kind}-file", path)
            page.until(f"document.getElementById('{kind}-image').naturalWidth > 0")
        page.click_image("target-image", 256, 256)
        page.until("document.getElementById('target-image').src.includes('mask')")
        page.evaluate("document.getElementById('run').click()")
        page.until("!document.getElementById('video').hidden && document.getElementById('video').readyState >= 2",
                   timeout=600)
        call("Emulation.setDeviceMetricsOverride", width=1100, height=1250, deviceScaleFactor=1, mobile=False)
        time.sleep(1.0)
        image = wait(lambda image: True)
    out = ROOT / "docs" / "images" / "app.png"
    cv2.imwrite(str(out), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene = make_scene("outofplane", num_frames=FRAMES, size=(320, 240), seed=0)
        clip = tmp / "clip.mp4"
        write_video(clip, scene.frames, scene.fps)
        photo = tmp / "photo.png"
        write_image(photo, render_object_image("vase", size=(512, 512), seed=0)[..., :3])
        app = serve_app(port=0, workdir=tmp / "work")
        try:
            results = [one_run(app, clip, photo) for _ in range(args.runs)]
            picture = screenshot(app, clip, photo)
        finally:
            app.stop()
    seconds = [s for s, _ in results]
    lines = ["# The local web app", "",
             f"`python benchmarks/bench_app.py` on {platform.machine()}, Python {platform.python_version()}: "
             f"a {FRAMES}-frame 320x240 synthetic clip and a 512x512 photo uploaded to `marionette app` through "
             "its HTTP API, the photo's object clicked, the video made with the default settings; time from the "
             f"start of the upload to the finished video, median of {args.runs} runs.", "",
             f"**Upload to video: {statistics.median(seconds):.1f} s** (runs: "
             + ", ".join(f"{s:.1f}" for s in seconds) + f"; {results[0][1]['frames']} frames out).", "",
             "The page after a run, in headless Chromium: "
             + ("[docs/images/app.png](../images/app.png)." if picture else "(no Chromium on this machine).")]
    OUT.write_text("\n".join(lines) + "\n")
    print(OUT.read_text())


if __name__ == "__main__":
    main()
