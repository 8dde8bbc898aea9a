"""Batch jobs on a real Dask cluster of two local workers: shared priors, skips, failures, safe outputs."""

import csv
import os
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import psutil
import pytest
from distributed import Client, get_task_stream

from marionette.batch import _remove_temporaries, local_cluster, read_jobs, run_batch
from marionette.errors import InputError
from marionette.io import read_prior, read_video, write_image, write_video
from marionette.io.atomic import atomic_path
from marionette.progress import Reporter
from marionette.synthetic import make_scene, render_object_image

pytestmark = pytest.mark.heavy

SOURCES = '''
[[source]]
name = "spin"
path = "spin.mp4"
masks = "spin_masks"
[[source]]
name = "slide"
path = "slide"
masks = "slide_masks"
'''
TARGETS = '''
[[target]]
path = "box.png"
[[target]]
name = "disc"
path = "disc.png"
'''


@pytest.fixture(scope="module")
def cluster():
    with local_cluster(2) as c:
        yield c


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Two 8-frame 96x72 sources (an .mp4 and a frame folder, with masks) and two 64x64 targets."""
    folder = tmp_path_factory.mktemp("inputs")
    for name, motion, video in (("spin", "inplane", "spin.mp4"), ("slide", "translation", "slide")):
        scene = make_scene(motion, num_frames=8, size=(96, 72), seed=3)
        write_video(folder / video, scene.frames, fps=12)
        (folder / f"{name}_masks").mkdir()
        for i, mask in enumerate(scene.masks):
            write_image(folder / f"{name}_masks" / f"{i:05d}.png", mask.astype(np.uint8) * 255)
    write_image(folder / "box.png", render_object_image("box", size=(64, 64)))
    disc = np.zeros((64, 64, 4), np.uint8)
    cv2.circle(disc, (32, 32), 20, (40, 160, 90, 255), -1)
    write_image(folder / "disc.png", disc)
    write_video(folder / "still.mp4", np.repeat(scene.frames[:1], 8, axis=0), fps=12)
    (folder / "broken.mp4").write_bytes(b"not a video at all")
    (folder / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    return folder


def write_jobs(folder, text, name="jobs.toml"):
    path = folder / name
    path.write_text(text)
    return path


def run_counting_tasks(jobs, cluster):
    """Run the batch on ``cluster``; its rows by job and the number of tasks of each kind."""
    with Client(cluster) as client, get_task_stream(client) as stream:
        rows = run_batch(jobs, scheduler=cluster.scheduler_address)
    kinds = [task["key"].split("-")[0] for task in stream.data]
    return {row.job: row for row in rows}, {k: kinds.count(k) for k in ("extract", "read", "job")}


def test_cluster_listens_on_localhost_only(cluster):
    procs = [psutil.Process(os.getpid()), *psutil.Process(os.getpid()).children(recursive=True)]
    listening = [c.laddr.ip for p in procs for c in p.net_connections("tcp") if c.status == psutil.CONN_LISTEN]
    assert len(listening) >= 3 and set(listening) == {"127.0.0.1"}


def test_priors_are_shared_finished_jobs_skipped_and_changes_rerun(inputs, cluster):
    jobs = write_jobs(inputs, 'output = "out"\n[defaults]\nmax_side = 96\n' + SOURCES + TARGETS)
    out = inputs / "out"
    rows, tasks = run_counting_tasks(jobs, cluster)
    assert sorted(rows) == ["slide__box", "slide__disc", "spin__box", "spin__disc"]
    assert {r.status for r in rows.values()} == {"ran"} and tasks == {"extract": 2, "read": 0, "job": 4}
    # The two jobs of a source report the same (single) extraction.
    assert rows["spin__box"].extract_s == rows["spin__disc"].extract_s > 0
    for row in rows.values():
        assert row.output == out / f"{row.job}.mp4"
        assert read_video(row.output).frames.shape == (8, 64, 64, 3)
    assert read_prior(out / "priors" / "spin.npz").num_frames == 8
    with open(out / "results.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["status"] for r in table] == ["ran"] * 4 and table[0]["output"] == "spin__box.mp4"
    assert (out / "results.md").read_text().count("| ran |") == 4

    prior_mtime = (out / "priors" / "spin.npz").stat().st_mtime_ns
    rows, tasks = run_counting_tasks(jobs, cluster)
    assert {r.status for r in rows.values()} == {"skipped"} and tasks == {"extract": 0, "read": 0, "job": 0}

    # A transfer option of one target re-runs only its jobs, on the priors written before.
    write_jobs(inputs, jobs.read_text().replace('path = "disc.png"', 'path = "disc.png"\nspeed = 0.5'))
    rows, tasks = run_counting_tasks(jobs, cluster)
    assert {j: r.status for j, r in rows.items()} == {"spin__box": "skipped", "spin__disc": "ran",
                                                      "slide__box": "skipped", "slide__disc": "ran"}
    assert tasks == {"extract": 0, "read": 2, "job": 2} and rows["spin__disc"].extract_s is None
    assert (out / "priors" / "spin.npz").stat().st_mtime_ns == prior_mtime

    # An extraction option of one source re-extracts it and re-runs all its jobs.
    write_jobs(inputs, jobs.read_text().replace('masks = "spin_masks"', 'masks = "spin_masks"\nsmooth = 0'))
    rows, tasks = run_counting_tasks(jobs, cluster)
    assert [j for j, r in rows.items() if r.status == "ran"] == ["spin__box", "spin__disc"]
    assert tasks == {"extract": 1, "read": 0, "job": 2}
    assert (out / "priors" / "spin.npz").stat().st_mtime_ns != prior_mtime


def test_failed_jobs_are_reported_and_the_others_finish(inputs, cluster, capsys):
    """A broken source and a broken target fail only their own jobs; workers' warnings reach the user."""
    jobs = write_jobs(inputs, '''output = "failing"
[defaults]
max_side = 96
frames = 4
[[source]]
path = "spin.mp4"
masks = "spin_masks"
[[source]]
path = "broken.mp4"
[[source]]
path = "still.mp4"
masks = "slide_masks"
[[target]]
path = "disc.png"
[[target]]
path = "broken.png"
[[job]]
source = "spin"
target = "disc"
[[job]]
source = "spin"
target = "broken"
[[job]]
source = "broken"
target = "disc"
[[job]]
source = "still"
target = "disc"
''', "failing.toml")
    rows = {row.job: row for row in run_batch(jobs, scheduler=cluster.scheduler_address, reporter=Reporter())}
    assert {j: r.status for j, r in rows.items()} == {"spin__disc": "ran", "spin__broken": "failed",
                                                      "broken__disc": "failed", "still__disc": "ran"}
    messages = capsys.readouterr().err
    assert "warning: still: " in messages and "failed: spin__broken: " in messages
    assert read_video(rows["spin__disc"].output).frames.shape[0] == 4
    for job in ("spin__broken", "broken__disc"):
        assert "broken" in rows[job].error and "\n" not in rows[job].error
        assert not rows[job].output.exists()
    table = (inputs / "failing" / "results.md").read_text()
    assert table.count("| failed |") == 2 and rows["spin__broken"].error.replace("|", "\\|") in table


def test_runs_on_its_own_local_cluster_by_default(inputs):
    jobs = write_jobs(inputs, '''[defaults]
frames = 3
[[source]]
path = "spin.mp4"
masks = "spin_masks"
[[target]]
path = "disc.png"
''', "default.toml")
    (row,) = run_batch(jobs, workers=1)
    assert (row.job, row.status) == ("spin__disc", "ran")
    assert read_video(inputs / "default-output" / "spin__disc.mp4").frames.shape[0] == 3


def test_ctrl_c_stops_the_batch_keeping_finished_outputs_only(inputs):
    """Ctrl-C in a terminal (SIGINT to the process group, workers included) ends the command at once."""
    jobs = write_jobs(inputs, '''output = "interrupted"
[defaults]
max_side = 96
[[source]]
path = "spin.mp4"
masks = "spin_masks"
[[target]]
path = "disc.png"
name = "quick"
frames = 3
[[target]]
path = "disc.png"
name = "endless"
frames = 5000
''', "interrupted.toml")
    out = inputs / "interrupted"
    # Its own session with SIGINT at its default, as in a terminal (see test_interrupt.py).
    proc = subprocess.Popen([sys.executable, "-m", "marionette", "batch", str(jobs), "--workers", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 300
    while not ((out / "spin__quick.mp4").is_file() and [*out.glob(".spin__endless.*.tmp.mp4")]):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[1] if proc.poll() else "slow"
        time.sleep(0.05)
    workers = psutil.Process(proc.pid).children(recursive=True)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)  # it used to wait for ever, a second Ctrl-C ignored
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "error: interrupted"
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert psutil.wait_procs(workers, timeout=10)[1] == []  # no worker left running
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "priors", "spin__quick.mp4"]
    assert [p.name for p in (out / "priors").iterdir()] == ["spin.npz"]
    assert read_video(out / "spin__quick.mp4").frames.shape[0] == 3


@pytest.mark.parametrize("text, message", [
    ("output = 'x'\n[[source]\n", "not valid TOML"),
    ("colour = 1\n" + SOURCES + TARGETS, "unknown key 'colour'"),
    ("[defaults]\nspeed = -1\n" + SOURCES + TARGETS, "speed must be a number in (0, 100]"),
    ("[defaults]\nloop = 'forever'\n" + SOURCES + TARGETS, "loop must be one of"),
    ("[defaults]\nmotion = 'camera'\n" + SOURCES + TARGETS, "motion must be one of"),
    ("[defaults]\nbackground = [300, 0, 0]\n" + SOURCES + TARGETS, "background must be"),
    ("[defaults]\nsize = '8x8'\n" + SOURCES + TARGETS, "size must be"),
    ("[defaults]\nfocal = 'wide'\n" + SOURCES + TARGETS, "focal must be 'auto' or a positive number"),
    ("[defaults]\ncamera = 'orbit'\ncamera_amount = 1e3\n" + SOURCES + TARGETS,
     "camera amount for orbit must be a number within -360..360"),
    (SOURCES + TARGETS + "[[job]]\nsource = 'spin'\ntarget = 'box'\nparts = 2\n", "parts cannot be set here"),
    (SOURCES + TARGETS + "[[job]]\nsource = 'spin'\ntarget = 'teapot'\n", "target 'teapot' is not"),
    (SOURCES + TARGETS + "[[job]]\nsource = ['spin']\ntarget = 'box'\n", "source ['spin'] is not"),
    (SOURCES + TARGETS + "[[job]]\nsource = 'spin'\ntarget = 'box'\n" * 2, "duplicate job name 'spin__box'"),
    (SOURCES + TARGETS.replace('"disc"', '"BOX"'), "duplicate name 'BOX'"),
    (SOURCES.replace('"spin.mp4"', '"missing.mp4"') + TARGETS, "path is not an existing path"),
    (SOURCES.replace('"spin_masks"', '"nowhere"') + TARGETS, "masks is not an existing folder"),
    (SOURCES + TARGETS.replace('"disc"', '"../disc"'), "name '../disc' must be"),
    (SOURCES + TARGETS.replace('"disc"', '"a/b"'), "name 'a/b' must be"),
    (SOURCES + TARGETS.replace('"disc"', '"/tmp/x"'), "name '/tmp/x' must be"),
    (SOURCES + TARGETS + "[[job]]\nsource = 'spin'\ntarget = 'box'\nname = '..'\n", "name '..' must be"),
    ("output = '../out'\n" + SOURCES + TARGETS, "must be a relative folder without '..'"),
    ("output = '/tmp/out'\n" + SOURCES + TARGETS, "must be a relative folder without '..'"),
])
def test_bad_job_files_are_rejected_before_anything_runs(inputs, text, message):
    jobs = write_jobs(inputs, text, "bad.toml")
    with pytest.raises(InputError) as info:
        run_batch(jobs, scheduler="tcp://127.0.0.1:1")  # never reached: the file is checked first
    assert message in str(info.value) and str(info.value).startswith("bad.toml: ")
    assert "\n" not in str(info.value)


def test_symlinks_cannot_lead_outputs_out_of_the_output_folder(inputs, tmp_path):
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (inputs / "linked").symlink_to(outside)
    jobs = write_jobs(inputs, 'output = "linked"\n' + SOURCES + TARGETS, "links.toml")
    with pytest.raises(InputError, match="leads outside"):
        read_jobs(jobs)
    out = inputs / "links-output"
    (out / "priors").mkdir(parents=True)
    (out / "spin__disc.mp4").symlink_to(outside / "victim.mp4")
    jobs = write_jobs(inputs, SOURCES + TARGETS, "links.toml")
    with pytest.raises(InputError, match="spin__disc.mp4 leads outside"):
        read_jobs(jobs)
    (out / "spin__disc.mp4").unlink()
    (out / "priors").rmdir()
    (out / "priors").symlink_to(outside)
    with pytest.raises(InputError, match="priors/spin.npz leads outside"):
        read_jobs(jobs)
    assert list(outside.iterdir()) == []


def test_temporaries_of_killed_writers_are_removed(tmp_path):
    """A worker killed mid-write (Ctrl-C) leaves atomic_path's temporary; the batch removes its own only."""
    writes = [atomic_path(tmp_path / name) for name in ("a.mp4", "a.b.mp4")]
    temporaries = [w.__enter__() for w in writes]  # never exited, as in a killed process
    for tmp in temporaries:
        tmp.write_bytes(b"partial")
    _remove_temporaries([tmp_path / "a.mp4"])
    assert [p.exists() for p in temporaries] == [False, True]


def test_options_merge_defaults_then_target_then_job(inputs):
    jobs = write_jobs(inputs, '''[defaults]
speed = 2.0
max-side = 80
background = "255,0,0"
format = "gif"
''' + SOURCES + TARGETS.replace('path = "disc.png"', 'path = "disc.png"\nspeed = 3\nsize = "32x48"') + '''
[[job]]
source = "spin"
target = "disc"
[[job]]
source = "slide"
target = "disc"
name = "slow"
speed = 0.5
size = [40, 30]
part_seed = { 0 = [10, 12] }
''', "merge.toml")
    batch = read_jobs(jobs, output=inputs / "elsewhere")
    assert batch.sources["spin"].options["max_side"] == 80 and batch.sources["spin"].options["parts"] == 1
    first, second = batch.jobs
    assert (first.name, first.options["speed"], first.options["size"]) == ("spin__disc", 3.0, (32, 48))
    assert (second.name, second.options["speed"], second.options["size"]) == ("slow", 0.5, (40, 30))
    assert second.options["part_seed"] == {0: (10.0, 12.0)} and second.options["background"] == (1.0, 0.0, 0.0)
    assert second.output == inputs / "elsewhere" / "slow.gif"


def test_a_failed_job_is_one_line_and_lists_no_output(inputs, capfd):
    """On its own local cluster (whose workers write to this process's stderr): no tracebacks, no ResourceWarnings."""
    from marionette.cli import main

    jobs = write_jobs(inputs, '''output = "one-fails"
[[source]]
path = "spin.mp4"
masks = "spin_masks"
max_side = 96
[[target]]
path = "disc.png"
frames = 3
[[target]]
path = "broken.png"
''', "one_fails.toml")
    assert main(["batch", str(jobs), "--workers", "1"]) == 1
    err = capfd.readouterr().err
    (line,) = [line for line in err.splitlines() if "spin__broken" in line or "broken.png" in line]
    assert line.startswith("failed: spin__broken: cannot read image ") and line.endswith(
        "broken.png (corrupt or not a PNG file)")
    assert "Traceback" not in err and "Warning" not in err and "unclosed" not in err, err
    folder = inputs / "one-fails"
    with open(folder / "results.csv", newline="") as f:
        rows = {row["job"]: row for row in csv.DictReader(f)}
    assert {job: (row["status"], row["output"]) for job, row in rows.items()} == {
        "spin__disc": ("ran", "spin__disc.mp4"), "spin__broken": ("failed", "")}
    assert (folder / "spin__disc.mp4").is_file()
    assert "spin__broken.mp4" not in (folder / "results.md").read_text()


def test_exit_code_1_for_failed_jobs_is_documented(capsys):
    import marionette.batch
    from marionette.cli import main

    assert "exits with code 1" in " ".join(marionette.batch.__doc__.split())
    assert main(["batch", "--help"]) == 0
    assert "Exit code 1 if some job failed" in " ".join(capsys.readouterr().out.split())
