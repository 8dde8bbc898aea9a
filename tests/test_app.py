"""The local web app: its API end to end, two sessions at once, bad uploads, and the page in headless Chromium."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.parse
import urllib.request

import cv2
import numpy as np
import pytest
from browser import CHROMIUM, Page, browser

from marionette.app import serve_app
from marionette.io import read_video, write_video
from marionette.synthetic import make_scene

pytestmark = pytest.mark.heavy

FRAMES = 8


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A small synthetic clip (.mp4) and a photo of a red disc and a blue square on grey (.png)."""
    folder = tmp_path_factory.mktemp("inputs")
    scene = make_scene("inplane", num_frames=FRAMES, size=(96, 80), seed=1)
    clip = folder / "clip.mp4"
    write_video(clip, scene.frames, scene.fps)
    photo = np.full((90, 120, 3), 128, np.uint8)
    cv2.circle(photo, (35, 45), 20, (30, 40, 210), -1)  # BGR: red
    cv2.rectangle(photo, (70, 25), (108, 65), (200, 60, 30), -1)  # blue
    image = folder / "photo.png"
    cv2.imwrite(str(image), photo)
    return clip, image


@pytest.fixture
def app(tmp_path):
    server = serve_app(port=0, workdir=tmp_path / "work")
    yield server
    server.stop()


def call(app, path, body=None, method="POST"):
    """(status, JSON reply) of an API call."""
    data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
    request = urllib.request.Request(app.url + path, data=data, method=method)
    try:
        with urllib.request.urlopen(request, timeout=60) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def finished(app, session, timeout=300):
    deadline = time.monotonic() + timeout
    while True:
        status, state = call(app, f"/api/status?session={session}", method="GET")
        assert status == 200
        if state["state"] in ("done", "error") or time.monotonic() > deadline:
            return state
        time.sleep(0.2)


def test_two_sessions_at_once_each_get_their_own_video(app, inputs):
    clip, image = inputs
    sessions = [call(app, "/api/session")[1]["session"] for _ in range(2)]
    assert sessions[0] != sessions[1]
    for session, speed in zip(sessions, (1.0, 0.5)):
        status, info = call(app, f"/api/upload?session={session}&kind=source&name=clip.mp4", clip.read_bytes())
        assert status == 200 and info["frames"] == FRAMES and (info["width"], info["height"]) == (96, 80)
        status, info = call(app, f"/api/upload?session={session}&kind=target&name=photo.png", image.read_bytes())
        assert status == 200 and (info["width"], info["height"]) == (120, 90)
    # A click on the square: the preview shows it green.
    status, reply = call(app, f"/api/mask?session={sessions[0]}&kind=target", {"points": [[89, 45]]})
    assert status == 200
    with urllib.request.urlopen(app.url + reply["preview"], timeout=10) as r:
        preview = cv2.imdecode(np.frombuffer(r.read(), np.uint8), cv2.IMREAD_COLOR)
    assert preview[45, 89, 1] > preview[45, 35, 1] + 40
    runs = [threading.Thread(target=call, args=(app, f"/api/run?session={s}",
                                                {"speed": speed, "target": {"points": [[89, 45]]}}))
            for s, speed in zip(sessions, (1.0, 0.5))]
    for run in runs:
        run.start()
    for run in runs:
        run.join()
    counts = []
    for session in sessions:
        state = finished(app, session)
        assert state["state"] == "done", state
        assert state["source"].startswith(f"source motion: 1 part over {FRAMES} frames, focal length")
        with urllib.request.urlopen(f"{app.url}/api/file?session={session}&name=result.mp4", timeout=10) as r:
            path = app.sessions.get(session).folder / "check.mp4"
            path.write_bytes(r.read())
        counts.append(read_video(path).frames.shape[0])
    assert counts == [FRAMES, 2 * FRAMES - 1]  # each session's own speed: nothing shared


@pytest.mark.parametrize("settings, message", [
    ({"speed": 0}, "speed must be within"),
    ({"camera": "crane"}, "camera must be one of"),
    ({"motion": "camera"}, "motion must be one of"),
    ({"parts": "many"}, "parts must be 'auto' or an integer"),
    ({"focal": -300}, "focal must be 'auto' or a positive number"),
])
def test_bad_run_settings_get_a_message(app, settings, message):
    session = call(app, "/api/session")[1]["session"]
    status, reply = call(app, f"/api/run?session={session}", settings)
    assert status == 400 and message in reply["error"]


def test_the_source_summary_names_lost_frames():
    from marionette.app.jobs import source_summary
    from marionette.prior import SpatPrior

    prior = SpatPrior.identity(30, fps=10, image_size=(64, 48), intrinsics=np.diag([55.4, 55.4, 1.0]),
                               centroid=np.zeros(3), radius=1.0, metadata={"failed_frames": {"0:4": "", "0:5": ""}})
    assert source_summary(prior) == ("source motion: 1 part over 30 frames, focal length 55 px; pose estimation "
                                     "failed at 2 part-frames, their poses interpolated")
    prior.metadata["failed_frames"] = {}
    assert source_summary(prior) == "source motion: 1 part over 30 frames, focal length 55 px"


def test_parts_and_focal_reach_the_extraction(app, inputs, monkeypatch):
    import marionette.app.jobs as jobs

    seen = {}

    def extract(source, **kwargs):
        seen.update(kwargs)
        raise jobs.InputError("stopped after the settings were seen")

    monkeypatch.setattr(jobs.pipeline, "extract", extract)
    session = call(app, "/api/session")[1]["session"]
    for kind, path in zip(("source", "target"), inputs):
        assert call(app, f"/api/upload?session={session}&kind={kind}&name={path.name}", path.read_bytes())[0] == 200
    assert call(app, f"/api/run?session={session}", {"parts": "auto", "focal": "auto"})[0] == 200
    assert finished(app, session)["message"] == "stopped after the settings were seen"
    assert seen["options"].parts == "auto" and seen["focal"] == "auto"


@pytest.mark.parametrize("name, data, message", [
    ("notes.txt", b"hello", "is not a video or an image"),
    ("clip.mp4", b"not a video at all", "cannot read video clip.mp4"),
    ("clip.mp4", b"", "is empty"),
])
def test_a_bad_upload_gets_a_message_and_the_server_keeps_serving(app, name, data, message):
    session = call(app, "/api/session")[1]["session"]
    status, reply = call(app, f"/api/upload?session={session}&kind=source&name={name}", data)
    assert status == 400 and message in reply["error"]
    assert not list(app.sessions.get(session).folder.glob("source.*"))
    assert call(app, "/api/session")[0] == 200  # still serving
    status, reply = call(app, f"/api/run?session={session}", {})
    assert status == 400 and "upload a source clip and a photo first" in reply["error"]
    assert call(app, "/api/status?session=nope", method="GET")[0] == 400
    assert call(app, f"/api/file?session={session}&name=../../etc/passwd", method="GET")[0] == 400


def test_the_app_command_prints_its_address_and_ctrl_c_exits_130(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "marionette", "app", "--port", "0", "--json", "--workdir",
                             str(tmp_path / "work")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        while lines[-1:] != ["}\n"]:
            lines.append(proc.stdout.readline())
            assert lines[-1], proc.stderr.read()
        summary = json.loads("".join(lines))
        with urllib.request.urlopen(summary["figures"]["url"], timeout=10) as page:
            assert page.status == 200 and b"motion-marionette" in page.read()
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium (apt-get install -y chromium)")
def test_chromium_upload_click_run_and_play(app, inputs):
    clip, image = inputs

    with browser(app.url) as (wait, call_devtools):
        page = Page(call_devtools)
        page.until("typeof session === 'string'")
        for kind, path in (("source", clip), ("target", image)):
            page.upload(f"{kind}-file", path)
            page.until(f"document.getElementById('{kind}-image').naturalWidth > 0")
        page.click_image("target-image", 89, 45)  # the blue square, as a user clicks it
        page.until("prompts.target.points.length === 1 && document.getElementById('target-image').src.includes('mask')")
        page.evaluate("document.getElementById('speed').value = '0.5'; document.getElementById('run').click()")
        page.until("!document.getElementById('video').hidden && document.getElementById('video').readyState >= 1")
        duration = page.evaluate("document.getElementById('video').duration")
        summary = page.evaluate("document.getElementById('summary').textContent")
        url = page.evaluate("document.getElementById('video').src")
        wait(lambda image: True)
    with urllib.request.urlopen(url, timeout=10) as r:
        data = r.read()
    path = app.sessions.root / "played.mp4"
    path.write_bytes(data)
    played = read_video(path)
    assert played.frames.shape[0] == 2 * FRAMES - 1  # half speed
    assert summary.startswith(f"source motion: 1 part over {FRAMES} frames")
    assert duration == pytest.approx(played.frames.shape[0] / played.fps, rel=0.2)


def test_a_work_folder_the_app_made_itself_goes_when_it_stops():
    server = serve_app(port=0)
    root = server.sessions.root
    assert root.is_dir()
    server.stop()
    assert not root.exists()


@pytest.mark.parametrize("kind, name, data", [
    ("source", "clip.mp4", b"not a video at all"),
    ("source", "clip.gif", b"GIF89a, no more"),
    ("source", "one frame.mp4", None),  # a video of one frame
    ("target", "photo.png", b"not a picture"),
    ("target", "photo.jpg", b"\xff\xd8\xff, no more"),
])
def test_an_upload_error_names_the_users_file_never_a_server_path(app, tmp_path, kind, name, data):
    if data is None:
        write_video(tmp_path / "one.mp4", np.zeros((1, 32, 32, 3), np.uint8), 10.0)
        data = (tmp_path / "one.mp4").read_bytes()
    session = call(app, "/api/session")[1]["session"]
    status, reply = call(app, f"/api/upload?session={session}&kind={kind}&name={urllib.parse.quote(name)}", data)
    assert status == 400 and name in reply["error"]
    assert "/" not in reply["error"], reply["error"]  # no path of the server's


def test_a_bad_upload_after_a_good_one_leaves_none_behind(app, inputs):
    session = call(app, "/api/session")[1]["session"]
    assert call(app, f"/api/upload?session={session}&kind=target&name=photo.png", inputs[1].read_bytes())[0] == 200
    assert call(app, f"/api/upload?session={session}&kind=target&name=photo.png", b"not a picture")[0] == 400
    status, reply = call(app, f"/api/mask?session={session}&kind=target", {"points": [[10, 10]]})
    assert status == 400 and reply["error"] == "upload the photo first"


@pytest.mark.parametrize("port", ["99999", "-1"])
def test_a_bad_port_is_one_line_and_leaves_no_work_folder(tmp_path, monkeypatch, capsys, port):
    import tempfile

    from marionette.cli import main

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where the app makes its work folder
    assert main(["app", "--port", port]) == 2
    assert capsys.readouterr().err.strip() == f"error: port must be in 0..65535 (0: any free port), got {port}"
    assert list(tmp_path.iterdir()) == []


def test_a_port_in_use_is_an_error_naming_it(tmp_path, monkeypatch, capsys):
    import socket
    import tempfile

    from marionette.cli import main

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        assert main(["app", "--port", str(port)]) == 2
    assert capsys.readouterr().err.strip() == f"error: port {port} is in use; --port 0 picks a free one"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("signum, group", [(signal.SIGINT, True), (signal.SIGTERM, False)], ids=["ctrl-c", "kill"])
def test_the_app_removes_its_own_work_folder_when_stopped(tmp_path, signum, group):
    """Ctrl-C (SIGINT to the process group) and ``kill`` (SIGTERM to the command) alike."""
    proc = subprocess.Popen([sys.executable, "-m", "marionette", "app", "--port", "0", "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "TMPDIR": str(tmp_path)},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        while lines[-1:] != ["}\n"]:
            lines.append(proc.stdout.readline())
            assert lines[-1], proc.stderr.read()
        workdir = json.loads("".join(lines))["figures"]["workdir"]
        assert [str(p) for p in tmp_path.iterdir()] == [workdir]
    finally:
        (os.killpg if group else os.kill)(proc.pid, signum)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["error: interrupted"]
    assert list(tmp_path.iterdir()) == []
