"""The README's Python example runs as written in an empty folder, and every repository path it or --help cites exists."""

import re
from pathlib import Path

import numpy as np
import pytest
from typer.main import get_command

from marionette.cli import app
from marionette.io import read_video

pytestmark = pytest.mark.heavy

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

#: A path into the repository: under one of its top folders, or a capitalised document such as DESIGN.md
#: (output names like results.md are lower case).
CITED = re.compile(r"(?<![\w./-])((?:docs|marionette|benchmarks|tests)/[\w./-]*\w|[A-Z][A-Z_]*\.md)")


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def help_texts() -> list[str]:
    """The help of the command group, of every command and of every option and argument."""
    group = get_command(app)
    texts = [group.help or ""]
    for command in group.commands.values():
        texts += [command.help or ""] + [getattr(param, "help", None) or "" for param in command.params]
    return texts


def test_readme_python_example_runs_as_written_in_an_empty_folder(tmp_path, monkeypatch, capsys):
    blocks = python_blocks()
    assert len(blocks) == 1 and "import marionette as mm" in blocks[0]
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[0], str(README), "exec"), {})
    printed = capsys.readouterr().out
    assert "1 part(s), 48 frames" in printed
    rigidity = float(re.search(r"rigidity error (\S+)", printed).group(1))
    assert rigidity < 1e-3
    video = read_video(tmp_path / "api.mp4")
    assert len(video.frames) == 60
    # the object turns: frames drift steadily away from the first one at half speed
    change = [np.abs(video.frames[i].astype(int) - video.frames[0]).mean() for i in (10, 30, 59)]
    assert 1 < change[0] < change[1] < change[2]


def test_every_path_the_readme_and_the_help_cite_exists():
    cited = {"README.md": set(CITED.findall(README.read_text(encoding="utf-8"))),
             "--help": set(CITED.findall("\n".join(help_texts())))}
    assert "docs/DESIGN.md" in cited["README.md"] and "docs/DESIGN.md" in cited["--help"]
    missing = {where: sorted(p for p in paths if not (ROOT / p).exists()) for where, paths in cited.items()}
    assert missing == {"README.md": [], "--help": []}


def test_api_names_are_the_functions_not_the_subpackages():
    import marionette as mm
    import marionette.render.camera_path  # noqa: F401  (submodule imports must not rebind the names)
    import marionette.transfer.parts  # noqa: F401

    assert callable(mm.transfer) and callable(mm.render) and callable(mm.lift_target)
    assert set(mm.__all__) <= set(dir(mm))
    assert all(getattr(mm, name) is not None for name in mm.__all__)  # every name resolves
    with pytest.raises(AttributeError, match="no attribute 'extrakt'"):
        mm.extrakt
