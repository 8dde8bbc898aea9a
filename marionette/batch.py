"""Many source × target jobs from one TOML file, run on Dask distributed.

A job file names the sources (videos or frame folders), the targets (images
or ``.ply``) and the jobs; every option has the name of the matching
``marionette run`` option (``max_side`` or ``max-side``) and a TOML value::

    output = "results"          # output folder, inside this file's folder
                                # (default "<file stem>-output")

    [defaults]                  # any option, for every source or job
    max_side = 480
    frames = 48
    background = [1.0, 1.0, 1.0]

    [[source]]                  # name (default: the file stem), path, extraction options
    name = "car"
    path = "videos/car-turn.mp4"
    masks = "videos/car-turn-masks"
    parts = 1                   # or "auto"

    [[target]]                  # name, path, transfer options
    name = "teapot"
    path = "images/teapot.png"
    size = [512, 512]           # or "512x512"

    [[job]]                     # optional: without [[job]], every source × target
    source = "car"
    target = "teapot"
    name = "car-fast"           # default "<source>__<target>"
    speed = 2.0

Extraction options (``[defaults]``, ``[[source]]``): masks, depth, focal,
parts, start, end, stride, max_side, smooth, joint_fit. Transfer options
(``[defaults]``, ``[[target]]``, ``[[job]]``; the later wins): frames, speed,
loop, reverse, rotation_scale, translation_scale, fps, background (``[R, G,
B]`` or ``"R,G,B"``, 0-1 or 0-255), size, camera, camera_amount,
camera_path, target_mask, anchor, motion (``"filmed"`` or ``"world"``),
part_seed (``{0 = [X, Y], …}``) and format (``"mp4"`` or ``"gif"``). Input
paths are relative to the job file.

The batch names every output itself, and only inside the output folder:
``priors/<source>.npz``, ``<job>.mp4`` (or ``.gif``), ``results.csv``,
``results.md`` and ``manifest.json``. Names are 1-64 letters, digits, ``.``,
``_`` or ``-`` starting with a letter or digit; resolved output paths must
stay inside the folder (no symlink leads out). The whole file is checked
before anything runs.

Each source's prior is extracted once, in one task, and the job tasks that
use it depend on its future. ``manifest.json`` keeps a hash of each
finished output's options and input files (name, size, mtime): on a re-run
an output whose hash still matches is skipped, a prior whose hash matches is
read back instead of extracted. A failed job is recorded in the results with
its one-line error; the others carry on (``marionette batch`` then exits
with code 1).

Ctrl-C (or SIGTERM) stops the batch: the cluster is closed, finished
outputs stay, the temporaries of unfinished ones are removed.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import logging
import math
import re
import signal
import time
import tomllib
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from . import pipeline
from .camera import MAX_IMAGE_SIDE
from .errors import InputError
from .io import read_prior, write_prior
from .io.atomic import check_output_dir, leftover_temporaries, write_text
from .options import parse_background, parse_focal, parse_part_seeds, parse_parts, parse_size
from .prior import MOTION_FRAMES, SpatPrior
from .progress import Reporter
from .render.camera_path import CAMERA_MOVES, check_camera_move
from .source import ExtractOptions
from .transfer.controls import LOOPS

__all__ = ["Batch", "Source", "Job", "JobResult", "read_jobs", "run_batch", "local_cluster"]

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
_MANIFEST_VERSION = 1
RESULT_COLUMNS = ("job", "source", "target", "output", "status", "extract_s", "transfer_render_s", "error")


# --- option checks: (value, folder of the job file) -> checked value; ValueError(reason) if bad --------------------

def _number(lo: float, hi: float, *, above: bool = False) -> Callable[[Any, Path], float]:
    def check(value, base):
        if (isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
                or value > hi or value < lo or (above and value == lo)):
            raise ValueError(f"must be a number in {'(' if above else '['}{lo}, {hi}]")
        return float(value)
    return check


def _integer(lo: int, hi: int) -> Callable[[Any, Path], int]:
    def check(value, base):
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise ValueError(f"must be an integer in [{lo}, {hi}]")
        return value
    return check


def _choice(*choices: str) -> Callable[[Any, Path], str]:
    def check(value, base):
        if value not in choices:
            raise ValueError(f"must be one of {', '.join(choices)}")
        return value
    return check


def _flag(value, base) -> bool:
    if not isinstance(value, bool):
        raise ValueError("must be true or false")
    return value


def _existing(kind: str) -> Callable[[Any, Path], Path]:
    """A path relative to the job file's folder that exists as a ``kind`` ('file', 'folder' or 'path')."""
    def check(value, base):
        if not isinstance(value, str) or not value:
            raise ValueError("must be a path string")
        path = base / value
        if not {"file": path.is_file, "folder": path.is_dir, "path": path.exists}[kind]():
            raise ValueError(f"is not an existing {kind}")
        return path
    return check


def _shared(parse: Callable[[Any], Any]) -> Callable[[Any, Path], Any]:
    """A parser of :mod:`marionette.options` (shared with the command line) as a check."""
    return lambda value, base: parse(value)


#: Extraction options: checks and the defaults of ``marionette run``.
EXTRACT_OPTIONS = {
    "masks": (_existing("folder"), None), "depth": (_existing("folder"), None),
    "focal": (_shared(parse_focal), None), "parts": (_shared(parse_parts), 1),
    "start": (_integer(0, 10**7), 0),
    "end": (_integer(1, 10**7), None), "stride": (_integer(1, 10**4), 1),
    "max_side": (_integer(16, MAX_IMAGE_SIDE), pipeline.DEFAULT_MAX_SIDE), "smooth": (_number(0, 100), 1.0),
    "joint_fit": (_flag, True),
}
#: Transfer and rendering options: checks and the defaults of ``marionette run``.
TRANSFER_OPTIONS = {
    "frames": (_integer(2, 100_000), None), "speed": (_number(0, 100, above=True), 1.0),
    "loop": (_choice(*LOOPS), "hold"), "reverse": (_flag, False),
    "rotation_scale": (_number(-100, 100), 1.0), "translation_scale": (_number(-100, 100), 1.0),
    "fps": (_number(0, 240, above=True), None), "background": (_shared(parse_background), (1.0, 1.0, 1.0)),
    "size": (_shared(parse_size), None), "camera": (_choice(*CAMERA_MOVES), "static"),
    "camera_amount": (_number(-1e4, 1e4), None), "camera_path": (_existing("file"), None),
    "target_mask": (_existing("file"), None), "anchor": (_choice("centroid", "world"), "centroid"),
    "motion": (_choice(*MOTION_FRAMES), "filmed"),
    "part_seed": (_shared(parse_part_seeds), None), "format": (_choice("mp4", "gif"), "mp4"),
}


@dataclass(frozen=True)
class Source:
    """A source video and its checked extraction options (keys of :data:`EXTRACT_OPTIONS`)."""

    name: str
    path: Path
    options: dict
    prior: Path  # output: the prior file


@dataclass(frozen=True)
class Job:
    """One transfer: a source's prior onto a target, with checked transfer options."""

    name: str
    source: str
    target: str
    target_path: Path
    options: dict  # keys of TRANSFER_OPTIONS
    output: Path


@dataclass(frozen=True)
class Batch:
    """A checked job file: what to run and where every output goes."""

    output: Path
    sources: dict[str, Source]
    jobs: list[Job]


@dataclass(frozen=True)
class JobResult:
    """One row of the results table; ``status`` is 'ran', 'skipped' or 'failed'.

    ``extract_s`` is the time of the source's extraction (shared by its jobs;
    None when the prior was read back), ``transfer_s`` of transfer and render.
    """

    job: str
    source: str
    target: str
    output: Path
    status: str
    extract_s: float | None = None
    transfer_s: float | None = None
    error: str = ""


# --- reading the job file ------------------------------------------------------------------------------------------

class _Reader:
    """Checks tables of a job file, naming the file and the table in every error."""

    def __init__(self, jobs_file: Path) -> None:
        self.file = jobs_file
        self.base = jobs_file.parent

    def fail(self, where: str, message: str) -> InputError:
        return InputError(f"{self.file.name}: {where}: {message}")

    def table(self, raw: Any, where: str, fields: tuple[str, ...], options: dict, other: dict | None = None) -> dict:
        """Keys normalised (``-`` → ``_``), unknown keys rejected, options checked."""
        if not isinstance(raw, dict):
            raise self.fail(where, "must be a table")
        out = {}
        for key, value in raw.items():
            name = key.replace("-", "_")
            if name in options:
                try:
                    out[name] = options[name][0](value, self.base)
                except ValueError as e:
                    raise self.fail(where, f"{key} {e}, got {value!r}") from None
            elif name in fields:
                out[name] = value
            elif other and name in other:
                raise self.fail(where, f"{key} cannot be set here (set it in [defaults] or the "
                                       f"{'[[source]]' if other is EXTRACT_OPTIONS else '[[target]] or [[job]]'})")
            else:
                raise self.fail(where, f"unknown key {key!r}")
        return out

    def name(self, value: Any, where: str) -> str:
        if not isinstance(value, str) or not _NAME.fullmatch(value):
            raise self.fail(where, f"name {value!r} must be 1-64 letters, digits, '.', '_' or '-', "
                                   "starting with a letter or digit")
        return value

    def entries(self, raw: Any, kind: str, options: dict, other: dict) -> dict[str, dict]:
        """``[[source]]`` or ``[[target]]`` tables by name, with the path checked."""
        if not isinstance(raw, list) or not raw:
            raise self.fail(f"[[{kind}]]", f"at least one [[{kind}]] table is needed")
        found: dict[str, dict] = {}
        for i, item in enumerate(raw):
            entry = self.table(item, f"[[{kind}]] #{i + 1}", ("name", "path"), options, other)
            if "path" not in entry:
                raise self.fail(f"[[{kind}]] #{i + 1}", "path is missing")
            try:
                entry["path"] = _existing("path" if kind == "source" else "file")(entry["path"], self.base)
            except ValueError as e:
                raise self.fail(f"[[{kind}]] #{i + 1}", f"path {e}, got {item['path']!r}") from None
            name = self.name(entry.pop("name", entry["path"].stem), f"[[{kind}]] #{i + 1}")
            if name.lower() in {n.lower() for n in found}:
                raise self.fail(f"[[{kind}]] #{i + 1}", f"duplicate name {name!r}")
            found[name] = entry
        return found


def _inside(folder: Path, path: Path, reader: _Reader, what: str) -> Path:
    """``path`` if, with symlinks resolved, it stays inside ``folder``."""
    if not path.resolve().is_relative_to(folder.resolve()):
        raise reader.fail("output", f"{what} {path} leads outside {folder}")
    return path


def read_jobs(jobs_file: str | Path, output: str | Path | None = None) -> Batch:
    """Read and check a job file (format in the module docstring) without running anything.

    ``output`` overrides the file's output folder (and may be anywhere);
    the file's own ``output`` must stay inside the job file's folder.
    Raises :class:`InputError` with a one-line message on any problem.
    """
    jobs_file = Path(jobs_file)
    if not jobs_file.is_file():
        raise InputError(f"job file {jobs_file} does not exist")
    try:
        raw = tomllib.loads(jobs_file.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{jobs_file.name}: not valid TOML: {str(e).splitlines()[0]}") from None
    except OSError as e:
        raise InputError(f"cannot read job file {jobs_file}: {e.strerror}") from None
    reader = _Reader(jobs_file)
    top = reader.table(raw, "top level", ("output", "defaults", "source", "target", "job"), {})
    defaults = reader.table(top.get("defaults", {}), "[defaults]", (), EXTRACT_OPTIONS | TRANSFER_OPTIONS)
    sources = reader.entries(top.get("source"), "source", EXTRACT_OPTIONS, TRANSFER_OPTIONS)
    targets = reader.entries(top.get("target"), "target", TRANSFER_OPTIONS, EXTRACT_OPTIONS)
    folder = _output_folder(reader, top.get("output", f"{jobs_file.stem}-output"), output)

    extract_defaults = _defaults(EXTRACT_OPTIONS, defaults)
    checked_sources = {
        name: Source(name, entry.pop("path"), extract_defaults | entry,
                     _inside(folder, folder / "priors" / f"{name}.npz", reader, "prior"))
        for name, entry in sources.items()}
    if "job" in top:
        if not isinstance(top["job"], list) or not top["job"]:
            raise reader.fail("[[job]]", "must be a list of tables")
        pairs = [reader.table(item, f"[[job]] #{i + 1}", ("name", "source", "target"), TRANSFER_OPTIONS,
                              EXTRACT_OPTIONS) for i, item in enumerate(top["job"])]
    else:
        pairs = [{"source": s, "target": t} for s in sources for t in targets]

    transfer_defaults = _defaults(TRANSFER_OPTIONS, defaults)
    jobs, names = [], set()
    for i, pair in enumerate(pairs):
        where = f"[[job]] #{i + 1}"
        for kind, known in (("source", sources), ("target", targets)):
            if not isinstance(pair.get(kind), str) or pair[kind] not in known:
                raise reader.fail(where, f"{kind} {pair.get(kind)!r} is not a [[{kind}]] name")
        source, target = pair.pop("source"), pair.pop("target")
        name = reader.name(pair.pop("name", f"{source}__{target}"), where)
        if name.lower() in names:
            raise reader.fail(where, f"duplicate job name {name!r}")
        names.add(name.lower())
        target_path, target_options = targets[target]["path"], {k: v for k, v in targets[target].items() if k != "path"}
        options = transfer_defaults | target_options | pair
        try:
            check_camera_move(options["camera"], options["camera_amount"])
        except InputError as e:
            raise reader.fail(where, str(e)) from None
        jobs.append(Job(name, source, target, target_path, options,
                        _inside(folder, folder / f"{name}.{options['format']}", reader, "output")))
    return Batch(folder, checked_sources, jobs)


def _defaults(options: dict, given: dict) -> dict:
    """The ``marionette run`` defaults of ``options``, updated by those of ``given`` that belong to them."""
    return {k: default for k, (_, default) in options.items()} | {k: v for k, v in given.items() if k in options}


def _output_folder(reader: _Reader, relative: Any, output: str | Path | None) -> Path:
    """``output`` if given, else the job file's ``output`` (which must stay inside the job file's folder)."""
    if output is None:
        if (not isinstance(relative, str) or not relative or Path(relative).is_absolute()
                or ".." in Path(relative).parts):
            raise reader.fail("output", f"must be a relative folder without '..', got {relative!r}")
        folder = _inside(reader.base, reader.base / relative, reader, "folder")
    else:
        folder = Path(output)
    if folder.exists() and not folder.is_dir():
        raise reader.fail("output", f"{folder} exists and is not a folder")
    return folder


# --- fingerprints and the manifest ---------------------------------------------------------------------------------

def _stat(path: Path) -> list:
    """Name, size and mtime of a file, or of each file in a folder (one level)."""
    files = sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else [path]
    return [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in files]


def _hash(options: dict, inputs: list[Path | None], *parents: str) -> str:
    """Hash of options, input files' stats and the hashes this output depends on."""
    stats = [None if p is None else _stat(p) for p in inputs]
    text = json.dumps([options, stats, parents], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def _source_hash(source: Source) -> str:
    o = source.options
    return _hash(o, [source.path, o["masks"], o["depth"]])


def _job_hash(job: Job, source_hash: str) -> str:
    o = job.options
    return _hash(o, [job.target_path, o["camera_path"], o["target_mask"]], source_hash)


def _read_manifest(path: Path) -> dict[str, dict[str, str]]:
    """The manifest, or empty tables if it is missing or unreadable (everything then runs)."""
    empty = {"priors": {}, "jobs": {}}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return empty
    if not isinstance(data, dict) or data.get("version") != _MANIFEST_VERSION:
        return empty
    return {k: {n: h for n, h in v.items() if isinstance(h, str)} if isinstance(v := data.get(k), dict) else {}
            for k in empty}


def _write_manifest(path: Path, manifest: dict) -> None:
    write_text(path, json.dumps({"version": _MANIFEST_VERSION} | manifest, indent=1, sort_keys=True))


# --- tasks (run on the workers) ------------------------------------------------------------------------------------

@contextlib.contextmanager
def _recorded_warnings() -> Iterator[list[str]]:
    """Collect the warnings raised inside as distinct one-line texts, for the client to show.

    ResourceWarnings stay hidden, as Python hides them by default: they are
    about the worker's housekeeping (imageio-ffmpeg leaves a finished
    decoder's pipes to the garbage collector), not about the job.
    """
    texts: list[str] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", ResourceWarning)
        yield texts
    texts.extend(dict.fromkeys(str(w.message).splitlines()[0] for w in caught))


def _extract_task(source: Source) -> tuple[SpatPrior, float, list[str]]:
    """Extract and write a source's prior; the prior, the seconds it took and its warnings."""
    start = time.perf_counter()
    o = source.options
    with _recorded_warnings() as messages:
        prior = pipeline.extract(source.path, masks=o["masks"], depth=o["depth"], focal=o["focal"],
                                 max_side=o["max_side"], start=o["start"], end=o["end"], stride=o["stride"],
                                 options=ExtractOptions(parts=o["parts"], smoothing=o["smooth"],
                                                        joint_fit=o["joint_fit"]))
        write_prior(source.prior, prior)
    return prior, time.perf_counter() - start, messages


def _read_prior_task(source: Source) -> tuple[SpatPrior, None, list[str]]:
    return read_prior(source.prior), None, []


def _job_task(job: Job, extracted: tuple[SpatPrior, float | None, list[str]]) -> tuple[float | None, float, list[str]]:
    """Transfer and render one job (as ``marionette run`` does); extraction and own seconds, warnings."""
    start = time.perf_counter()
    prior, extract_s, _ = extracted
    o = job.options
    with _recorded_warnings() as messages:
        lifted = pipeline.load_target(job.target_path, size=o["size"], mask=o["target_mask"], prior=prior)
        trajectory = pipeline.transfer(prior, lifted, frames=o["frames"], speed=o["speed"], loop=o["loop"],
                                       reverse=o["reverse"], rotation_scale=o["rotation_scale"],
                                       translation_scale=o["translation_scale"], anchor=o["anchor"],
                                       motion=o["motion"], part_seeds=o["part_seed"])
        cameras = pipeline.output_cameras(lifted, trajectory, o["camera"], o["camera_amount"], o["camera_path"])
        pipeline.render_video(job.output, lifted, trajectory, cameras, fps=o["fps"] or prior.fps,
                              background=o["background"])
    return extract_s, time.perf_counter() - start, messages


def _remove_temporaries(outputs: list[Path]) -> None:
    """Delete the temporary files that workers killed mid-write left for ``outputs``."""
    for path in outputs:
        for tmp in leftover_temporaries(path):
            tmp.unlink(missing_ok=True)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return text if isinstance(exc, InputError) else f"{type(exc).__name__}: {text}".rstrip(": ")


# --- running -------------------------------------------------------------------------------------------------------

def local_cluster(workers: int = 2):
    """A Dask LocalCluster of ``workers`` single-threaded processes, every socket on 127.0.0.1.

    Its processes log only critical errors: a failed task comes back to the
    client, which reports it as one line, so the workers' own log of it (a
    traceback) would only repeat it. Its threads and processes keep SIGINT
    blocked: Ctrl-C in a terminal reaches the whole process group, and only
    the client should take it (it closes the cluster); a worker would die
    with a traceback and its task be run again.
    """
    from multiprocessing import resource_tracker

    from distributed import LocalCluster

    # A new thread or process inherits its creator's signal mask: the cluster's event loop thread, which
    # starts (and restarts) the workers, and the workers' own threads and subprocesses. Starting
    # multiprocessing's resource tracker unblocks SIGINT in the thread that starts it: started here, first.
    resource_tracker.ensure_running()
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                            dashboard_address="127.0.0.1:0", silence_logs=logging.CRITICAL)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def _client(scheduler: str | None, workers: int, stack: contextlib.ExitStack):
    """A Dask client of a new local cluster (closed with ``stack``) or of the scheduler at ``scheduler``."""
    from distributed import Client

    if scheduler is None:
        return Client(stack.enter_context(local_cluster(workers)))
    try:
        return Client(scheduler, timeout="20s")
    except (OSError, ValueError) as e:
        raise InputError(f"cannot reach the Dask scheduler {scheduler}: {_one_line(e)}") from None


def _submit(client, sources: dict[str, Source], pending: list[Job], done_priors: dict[str, str],
            source_hashes: dict[str, str]) -> tuple[dict, dict]:
    """Submit one prior task per source (extract it, or read back an up-to-date one) and the jobs after it.

    Returns the prior futures' source names and the job futures' jobs.
    """
    priors = {}
    for name in dict.fromkeys(job.source for job in pending):
        source = sources[name]
        reuse = source.prior.is_file() and done_priors.get(name) == source_hashes[name]
        task, kind = (_read_prior_task, "read-prior") if reuse else (_extract_task, "extract")
        priors[name] = client.submit(task, source, key=f"{kind}-{name}-{uuid.uuid4().hex[:8]}")
    jobs = {client.submit(_job_task, job, priors[job.source], key=f"job-{job.name}-{uuid.uuid4().hex[:8]}"): job
            for job in pending}
    return {future: name for name, future in priors.items()}, jobs


def run_batch(jobs_file: str | Path, scheduler: str | None = None, workers: int = 2,
              reporter: Reporter | None = None, output: str | Path | None = None) -> list[JobResult]:
    """Run every job of ``jobs_file``; write and return the results table (one row per job).

    On a local cluster of ``workers`` processes by default, or on the Dask
    scheduler at ``scheduler`` (e.g. ``"tcp://10.0.0.5:8786"``; its workers
    must see the same files). ``output`` overrides the job file's output
    folder. The file is checked completely before anything runs.
    """
    from distributed import as_completed

    reporter = reporter or Reporter(quiet=True)
    batch = read_jobs(jobs_file, output)
    if scheduler is None and not 1 <= workers <= 64:
        raise InputError(f"workers must be within 1..64, got {workers}")
    check_output_dir(batch.output)
    (batch.output / "priors").mkdir(parents=True, exist_ok=True)
    manifest_path = batch.output / "manifest.json"
    manifest = _read_manifest(manifest_path)

    source_hashes = {name: _source_hash(s) for name, s in batch.sources.items()}
    job_hashes = {job.name: _job_hash(job, source_hashes[job.source]) for job in batch.jobs}
    results = {job.name: JobResult(job.name, job.source, job.target, job.output, "skipped") for job in batch.jobs
               if job.output.is_file() and manifest["jobs"].get(job.name) == job_hashes[job.name]}
    pending = [job for job in batch.jobs if job.name not in results]

    try:
        # The client only waits for the cluster: Ctrl-C must raise at once, not at a progress call.
        with (reporter.stage("batch jobs", len(batch.jobs), defer_interrupt=False) as progress,
              contextlib.ExitStack() as stack):
            progress(len(results), len(batch.jobs))
            if pending:
                client = stack.enter_context(_client(scheduler, workers, stack))
                source_of, jobs = _submit(client, batch.sources, pending, manifest["priors"], source_hashes)
                for future in as_completed([*source_of, *jobs]):
                    if future in source_of:  # record a prior once written, whatever its jobs do
                        if future.status == "finished":
                            name = source_of[future]
                            manifest["priors"][name] = source_hashes[name]
                            _write_manifest(manifest_path, manifest)
                            for text in future.result()[2]:
                                reporter.message(f"warning: {name}: {text}")
                        continue
                    job = jobs[future]
                    if future.status == "finished":
                        extract_s, transfer_s, messages = future.result()
                        for text in messages:
                            reporter.message(f"warning: {job.name}: {text}")
                        results[job.name] = JobResult(job.name, job.source, job.target, job.output, "ran",
                                                      extract_s, transfer_s)
                        manifest["jobs"][job.name] = job_hashes[job.name]
                        _write_manifest(manifest_path, manifest)
                        reporter.detail(f"  {job.name}: transfer and render {transfer_s:.2f} s")
                    else:
                        error = _one_line(future.exception())
                        results[job.name] = JobResult(job.name, job.source, job.target, job.output, "failed",
                                                      error=error)
                        reporter.message(f"failed: {job.name}: {error}")
                    progress(len(results), len(batch.jobs))
    finally:  # workers stopped mid-write (Ctrl-C closes the cluster) leave temporary files behind
        _remove_temporaries([job.output for job in pending] + [s.prior for s in batch.sources.values()])

    rows = [results[job.name] for job in batch.jobs]
    _write_tables(batch.output, rows)
    counts = {s: sum(r.status == s for r in rows) for s in ("ran", "skipped", "failed")}
    reporter.message(f"{counts['ran']} ran, {counts['skipped']} skipped, {counts['failed']} failed; "
                     f"results in {batch.output / 'results.md'}")
    return rows


def _cells(row: JobResult, folder: Path) -> list[str]:
    seconds = ["" if s is None else f"{s:.2f}" for s in (row.extract_s, row.transfer_s)]
    output = "" if row.status == "failed" else str(row.output.relative_to(folder))
    return [row.job, row.source, row.target, output, row.status, *seconds, row.error]


def _write_tables(folder: Path, rows: list[JobResult]) -> None:
    """``results.csv`` and ``results.md``: one row per job, output paths relative to ``folder`` (none if failed)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(RESULT_COLUMNS)
    writer.writerows(_cells(row, folder) for row in rows)
    write_text(folder / "results.csv", buffer.getvalue())
    lines = ["| " + " | ".join(RESULT_COLUMNS) + " |", "|" + "---|" * len(RESULT_COLUMNS)]
    lines += ["| " + " | ".join(c.replace("|", "\\|") for c in _cells(row, folder)) + " |" for row in rows]
    write_text(folder / "results.md", "\n".join(lines) + "\n")
