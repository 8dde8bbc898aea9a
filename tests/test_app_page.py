"""The app's page in headless Chromium as a new user meets it: nothing broken or empty before an upload, the
pictures after one, the player once a run is done; screenshots checked as well as the page's elements."""

import json

import cv2
import numpy as np
import pytest
from browser import CHROMIUM, Page, browser

import marionette.app.jobs as jobs
from marionette.app import serve_app
from marionette.io import write_video

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium (apt-get install -y chromium)")

#: The page's elements, by when a user should see them.
FIRST = ("source-file", "target-file", "run", "summary")
AFTER_UPLOAD = ("source-image", "target-image", "source-clear", "target-clear")
AFTER_RUN = ("progress", "video", "download")
MAGENTA = (255, 0, 255)


@pytest.fixture
def app(tmp_path):
    server = serve_app(port=0, workdir=tmp_path / "work")
    yield server
    server.stop()


@pytest.fixture
def inputs(tmp_path):
    """A two-frame grey clip (.mp4) and a photo with a red disc (.png)."""
    clip = tmp_path / "clip.mp4"
    write_video(clip, np.full((2, 48, 64, 3), 128, np.uint8), 10.0)
    photo = np.full((90, 120, 3), 128, np.uint8)
    cv2.circle(photo, (60, 45), 30, (30, 40, 210), -1)  # BGR: red
    image = tmp_path / "photo.png"
    cv2.imwrite(str(image), photo)
    return clip, image


def visible(page: Page, ids) -> dict[str, bool]:
    """Whether each element is shown (rendered, not hidden by itself or an ancestor)."""
    return page.evaluate(f"Object.fromEntries({json.dumps(list(ids))}"
                         ".map((id) => [id, document.getElementById(id).checkVisibility()]))")


def broken_images(page: Page) -> list[str]:
    """Ids of the images shown without a picture (a broken-image icon)."""
    return page.evaluate("[...document.images].filter((i) => i.checkVisibility() && !(i.complete && i.naturalWidth))"
                         ".map((i) => i.id)")


def near(image: np.ndarray, colour) -> np.ndarray:
    """(H, W) bool: pixels of an RGB screenshot within 60 of ``colour`` in each channel (video coding shifts it)."""
    return (np.abs(image.astype(int) - colour) < 60).all(axis=2)


def blocks(mask: np.ndarray, side: int = 24) -> bool:
    """Whether ``mask`` holds a solid ``side`` x ``side`` square (a picture, not text or a border)."""
    return bool(cv2.erode(mask.astype(np.uint8), np.ones((side, side), np.uint8)).any())


def open_page(call) -> Page:
    page = Page(call)
    call("Emulation.setDeviceMetricsOverride", width=1000, height=1000, deviceScaleFactor=1, mobile=False)
    page.until("typeof session === 'string'")
    return page


def upload_both(page: Page, clip, image) -> None:
    for kind, path in (("source", clip), ("target", image)):
        page.upload(f"{kind}-file", path)
        page.until(f"document.getElementById('{kind}-image').naturalWidth > 0")


def test_before_an_upload_nothing_is_broken_or_empty(app):
    with browser(app.url) as (wait, call):
        page = open_page(call)
        shot = wait(lambda image: True)
        below_header = round(page.evaluate("document.querySelector('header').getBoundingClientRect().bottom"))
        assert visible(page, FIRST) == dict.fromkeys(FIRST, True)
        assert visible(page, AFTER_UPLOAD + AFTER_RUN) == dict.fromkeys(AFTER_UPLOAD + AFTER_RUN, False)
        assert broken_images(page) == []
    assert not blocks(shot[below_header:].max(axis=2) < 100)  # no empty player (black, greyed by its controls)


def test_a_file_dropped_beside_the_drop_zones_does_not_leave_the_page(app):
    with browser(app.url) as (_, call):
        page = open_page(call)
        assert page.evaluate("(() => { const drop = new DragEvent('drop', {bubbles: true, cancelable: true});"
                             " document.querySelector('header').dispatchEvent(drop);"
                             " return drop.defaultPrevented; })()")


def test_an_upload_shows_its_picture_and_a_bad_one_names_the_file(app, inputs, tmp_path):
    clip, image = inputs
    with browser(app.url) as (wait, call):
        page = open_page(call)
        upload_both(page, clip, image)
        shot = wait(lambda image: blocks(near(image, (210, 40, 30))))
        assert visible(page, AFTER_UPLOAD) == dict.fromkeys(AFTER_UPLOAD, True)
        assert visible(page, AFTER_RUN) == dict.fromkeys(AFTER_RUN, False)
        assert broken_images(page) == []
        assert page.evaluate("document.getElementById('run').disabled") is False

        broken = tmp_path / "broken.png"
        broken.write_bytes(b"not a picture")
        page.upload("target-file", broken)
        page.until("document.getElementById('message').textContent")
        message = page.evaluate("document.getElementById('message').textContent")
        assert visible(page, ("target-image", "target-clear")) == {"target-image": False, "target-clear": False}
        assert page.evaluate("document.getElementById('run').disabled") is True
    assert blocks(near(shot, (210, 40, 30)))  # the photo is on the screen
    assert message == "cannot read image broken.png (corrupt or not a PNG file)"


def test_a_finished_run_shows_the_player(app, inputs, monkeypatch):
    def run(session, settings):  # the page's part only: the pipeline has tests of its own (test_app.py)
        write_video(session.folder / "result.mp4", np.full((4, 64, 64, 3), MAGENTA, np.uint8), 10.0)
        session.status.update(state="done", stage="done", progress=1.0, frames=4, seconds=0.1, video="result.mp4",
                              source="source motion: 1 part over 2 frames")

    monkeypatch.setattr(jobs.Session, "run", run)
    with browser(app.url) as (wait, call):
        page = open_page(call)
        upload_both(page, *inputs)
        page.evaluate("document.getElementById('run').click()")
        page.until("document.getElementById('video').readyState >= 2")
        shot = wait(lambda image: blocks(near(image, MAGENTA)))
        assert visible(page, AFTER_RUN) == dict.fromkeys(AFTER_RUN, True)
        assert page.evaluate("document.getElementById('summary').textContent") == "source motion: 1 part over 2 frames"
    assert blocks(near(shot, MAGENTA))  # the video plays on the screen
