"""The README's examples run as written from an empty folder, and every repository path or link it, the user's
pages or --help cite exists."""

import json
import os
import re
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from typer.main import get_command

from marionette.cli import app
from marionette.io import read_video

pytestmark = pytest.mark.heavy

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: The pages a new user reads first; their relative links must lead somewhere.
USER_PAGES = [README, ROOT / "docs" / "guide.md", ROOT / "docs" / "limitations.md"]
#: Commands that serve a page until Ctrl-C.
SERVERS = ("marionette app", "marionette view")

#: A path into the repository: under one of its top folders, or a capitalised document such as DESIGN.md
#: (output names like results.md are lower case).
CITED = re.compile(r"(?<![\w./-])((?:docs|marionette|benchmarks|tests)/[\w./-]*\w|[A-Z][A-Z_]*\.md)")


def python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)


def bash_commands() -> list[str]:
    """The README's bash blocks as the commands a user types, in order, without comments: a here-document with its
    body, and of a line joined by ``&&`` every part but those that install the package or run the test suite."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S):
        lines = iter(block.splitlines())
        for line in lines:
            if "<<'EOF'" in line:
                body = [line]
                while body[-1] != "EOF":
                    body.append(next(lines))
                commands.append("\n".join(body))
                continue
            parts = [part.strip() for part in re.sub(r"\s+# .*", "", line).split("&&")]
            commands += [part for part in parts if part and not part.startswith(("python3 -m pip", "python3 -m pytest"))]
    return commands


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


def test_every_command_the_readme_shows_runs_from_an_empty_folder(tmp_path):
    """Each exits 0 on the files the README's earlier commands made; the servers answer, then Ctrl-C ends them.

    Slow for a test (about a minute on two cores: the demo, one extraction and one motion-fidelity measurement
    on the demo's 48 small frames), as a new user's first commands are.
    """
    commands = bash_commands()
    assert commands[0] == "marionette demo -o demo_out"  # the set-up's demo makes the files the rest use
    assert [c for c in commands if c.startswith(SERVERS)] == ["marionette view orbit_ply", "marionette app"]
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    for command in commands:
        if command.startswith(SERVERS):
            _serve_and_stop(command, tmp_path, env)
            continue
        done = subprocess.run(["bash", "-c", command], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=600)
        assert done.returncode == 0, f"{command}\n{done.stderr}"
    for made in ("motion.npz", "motion.png", "slow.mp4", "slow.gif", "orbit.mp4", "camera.json", "view.png"):
        assert (tmp_path / made).is_file(), made


def _serve_and_stop(command: str, folder: Path, env: dict) -> None:
    """Start a serving command (on any free port, so as not to meet another), fetch its page, Ctrl-C it: 130."""
    proc = subprocess.Popen(["bash", "-c", f"exec {command} --port 0 --json"], cwd=folder, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        lines = []
        while lines[-1:] != ["}\n"]:
            lines.append(proc.stdout.readline())
            assert lines[-1], f"{command}\n{proc.stderr.read()}"
        with urllib.request.urlopen(json.loads("".join(lines))["figures"]["url"], timeout=30) as page:
            assert page.status == 200, command
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, f"{command}\n{err}"


def test_the_readme_is_short_and_names_no_file_a_new_user_lacks():
    """Options, figures and limitations live in docs/; examples use the files the tool makes."""
    text = README.read_text(encoding="utf-8")
    assert len(text) <= 12_000
    assert not re.search(r"\b(car\.mp4|teapot\.png|photo\.jpg)\b", text)


def test_every_link_of_the_user_pages_leads_somewhere():
    broken = {}
    for page in USER_PAGES:
        links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text(encoding="utf-8"))
        missing = [link for link in links if "://" not in link and not (page.parent / link).exists()]
        if missing:
            broken[page.name] = missing
    assert broken == {}
