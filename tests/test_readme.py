"""The README's Python example runs as written, on the demo's files."""

import re
from pathlib import Path

import numpy as np

from marionette.demo import run_demo
from marionette.io import read_video

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def test_readme_python_example_runs(tmp_path, monkeypatch, capsys):
    blocks = python_blocks()
    assert len(blocks) == 1 and "import marionette as mm" in blocks[0]
    run_demo(tmp_path / "demo_out")
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[0], str(README), "exec"), {})
    printed = capsys.readouterr().out
    assert "1 part(s), 48 frames" in printed
    rigidity = float(re.search(r"rigidity error (\S+)", printed).group(1))
    assert rigidity < 1e-3
    video = read_video(tmp_path / "demo_out" / "api.mp4")
    assert len(video.frames) == 60
    # the object turns: frames drift steadily away from the first one at half speed
    change = [np.abs(video.frames[i].astype(int) - video.frames[0]).mean() for i in (10, 30, 59)]
    assert 1 < change[0] < change[1] < change[2]


def test_api_names_are_the_functions_not_the_subpackages():
    import marionette as mm
    import marionette.render.camera_path  # noqa: F401  (submodule imports must not rebind the names)
    import marionette.transfer.parts  # noqa: F401

    assert callable(mm.transfer) and callable(mm.render) and callable(mm.lift_target)
    assert set(mm.__all__) <= set(dir(mm))
