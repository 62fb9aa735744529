"""``pointrig batch``: many recordings, one output folder each, and a summary.

Each input ``INPUT`` is one job: read it, run :func:`pointrig.pipeline.extract` into
``OUT/<name>/`` (the usual output set, whole or absent, :mod:`pointrig.io.outdir`), and give
one :class:`BatchRow` (frames, joints, seconds, warnings, failure). A job that fails (bad
input, a full disk, an internal error, a worker process that died) is recorded as failed; the
other jobs go on. At the end ``OUT/summary.csv`` and ``OUT/index.html`` (the table, each
recording linked to its ``report.html``) are written.

Where the jobs run:

- one after the other in this process (``jobs=1``, the default);
- ``jobs=N`` processes on this machine at once, each a fresh Python process
  (``python -m pointrig.batch``) whose thread pools are capped to ``threads`` (default
  ``cores // N``) so that N x threads = cores: ``RAYON_NUM_THREADS`` (the Rust kernels),
  ``OPENBLAS_NUM_THREADS``/``OMP_NUM_THREADS``/``MKL_NUM_THREADS`` (numpy's BLAS) in its
  environment, and the config's ``workers`` fields;
- on an existing Dask distributed cluster (``scheduler="tcp://host:8786"``, the ``batch``
  extra): one task per recording; each sets the config's ``workers`` fields to ``threads``
  (default 1). The workers must see the same file system (inputs and ``OUT``).

The result of a recording does not depend on where it ran: the pipeline gives the same result
whatever its thread counts.
"""

from __future__ import annotations

import csv
import logging
import os
import pickle
import subprocess
import sys
import time
import traceback
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .config import PipelineConfig
from .errors import ConfigError, PointrigError
from .io.atomic import atomic_path
from .io.outdir import FRAMES, OutputDir, check_output_dir

__all__ = ["HEADER", "BatchOptions", "BatchResult", "BatchRow", "Job", "format_table",
           "plan_jobs", "read_recording", "run_batch", "run_job"]

log = logging.getLogger(__name__)

#: the columns of the printed summary table (``summary.csv`` adds ``input``)
HEADER = ("recording", "frames", "joints", "time s", "warnings", "failure")
#: the environment variables that cap a worker process's thread pools
THREAD_ENV = ("RAYON_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
              "MKL_NUM_THREADS")
_DASK_EXTRA = ("pointrig batch --scheduler needs the batch extra (dask distributed): "
               "pip install 'pointrig[batch]'")


@dataclass(frozen=True)
class BatchOptions:
    """What every recording of a batch is read and extracted with."""

    config: PipelineConfig = field(default_factory=PipelineConfig)
    pictures: bool = True  #: skeleton.png and skeleton.gif
    resume: bool = True  #: reuse a matching registration checkpoint in ``OUT/<name>``
    scale: float = 1.0  #: multiply coordinates to get metres
    intrinsics: str | None = None  #: camera intrinsics JSON for depth PNGs
    topic: str | None = None  #: ROS bags: the topic to read
    #: depth range and pixel box kept of depth images (``pointrig.io.depthcam.Isolation``)
    isolation: Any = None
    skip_bad_frames: bool = False  #: leave out unreadable frame files, with a warning


@dataclass(frozen=True)
class Job:
    """One recording of a batch."""

    name: str  #: the recording's name, its folder in ``OUT``
    input: str  #: the recording (absolute path)
    output: str  #: ``OUT/<name>`` (absolute path)
    options: BatchOptions
    threads: int = 0  #: threads for the job (0: leave the pools as they are)


@dataclass
class BatchRow:
    """The outcome of one recording."""

    recording: str
    input: str
    frames: int | None = None
    joints: int | None = None
    time_s: float = 0.0  #: reading and extraction, wall seconds
    warnings: list[str] = field(default_factory=list)
    failure: str = ""  #: the one-line error, empty when the recording succeeded
    report: bool = False  #: whether ``OUT/<name>/report.html`` was written

    def cells(self) -> list[str]:
        """The row of the printed table, in :data:`HEADER`'s order."""
        return [self.recording, "" if self.frames is None else str(self.frames),
                "" if self.joints is None else str(self.joints), f"{self.time_s:.1f}",
                str(len(self.warnings)), self.failure]


@dataclass
class BatchResult:
    """What :func:`run_batch` did: one row per input, in the inputs' order."""

    rows: list[BatchRow]
    summary: Path  #: ``OUT/summary.csv``
    index: Path  #: ``OUT/index.html``

    @property
    def failed(self) -> list[BatchRow]:
        """The rows of the recordings that failed."""
        return [r for r in self.rows if r.failure]


def plan_jobs(inputs: Sequence[str | Path], out: str | Path, options: BatchOptions,
              threads: int = 0) -> list[Job]:
    """One :class:`Job` per input, named by its file or folder name without the suffix
    (``-2``, ``-3``, ... appended to repeated names), writing into ``out/<name>``."""
    if not inputs:
        raise ConfigError("pointrig batch needs at least one input")
    root = Path(out).absolute()
    jobs, seen = [], set()
    for path in inputs:
        p = Path(path).absolute()
        base = (p.name if p.is_dir() else p.stem) or "recording"
        name, k = base, 1
        while name.lower() in seen:
            k += 1
            name = f"{base}-{k}"
        seen.add(name.lower())
        jobs.append(Job(name, str(p), str(root / name), options, threads))
    return jobs


def read_recording(path: str | Path, config: PipelineConfig, *, scale: float = 1.0,
                   intrinsics: str | Path | None = None, topic: str | None = None,
                   isolation: object = None, skip_bad_frames: bool = False,
                   spill: str | os.PathLike | None = None,
                   background_note: Callable[[str], None] | None = None):
    """Read a recording as ``pointrig extract`` does: the frames and crop of ``[preprocess]``,
    the units checked (metres), static background planes removed under ``[preprocess]
    background = "auto"`` (``background_note`` is given the removal's summary line); the
    reduced frames are kept on disk in the folder ``spill`` (read back on demand) when given.

    Returns
    -------
    PointSequence
        Frames ``(N_t, 3)``, metres, camera frame.
    """
    from .background import remove_background
    from .io import read_sequence
    from .sequence import check_units

    pre = config.preprocess  # its choices were checked when the config was made
    seq = read_sequence(
        path, start=pre.frame_start, stop=pre.frame_stop, stride=pre.frame_stride,
        crop_min=pre.crop_min, crop_max=pre.crop_max, voxel_size=pre.voxel_size,
        intrinsics=intrinsics, scale=scale, min_points=pre.min_points, topic=topic,
        isolation=isolation, skip_bad_frames=skip_bad_frames, spill=spill,
    )
    # before the background search, whose thresholds are metres too
    check_units(seq, pre.max_extent)
    if pre.background == "auto":
        seq, report = remove_background(seq, seed=config.registration.seed,
                                        threshold=pre.background_threshold)
        if report.planes and background_note is not None:
            background_note(report.summary())
    return seq


def run_job(job: Job) -> BatchRow:
    """Run one recording in this process and return its row; never raises for a failed
    recording (its one-line error goes to :attr:`BatchRow.failure`)."""
    from .pipeline import extract

    row = BatchRow(job.name, job.input)
    opts = job.options
    t0 = time.perf_counter()
    try:
        config = opts.config.with_workers(job.threads)
        # the output folder checked and locked before the input is read; the frames wait on
        # disk in its staging folder, as for extract
        with OutputDir(job.output) as od:
            seq = read_recording(job.input, config, scale=opts.scale,
                                 intrinsics=opts.intrinsics, topic=opts.topic,
                                 isolation=opts.isolation,
                                 skip_bad_frames=opts.skip_bad_frames,
                                 spill=od.staged(FRAMES))
            res = extract(seq, config, od, resume=opts.resume, pictures=opts.pictures)
        row.frames = res.skeleton.n_frames if res.skeleton is not None else len(seq)
        row.joints = res.skeleton.n_joints if res.skeleton is not None else None
        row.warnings = list(res.warnings)
        row.report = "report" in res.files
    except PointrigError as exc:
        row.failure = str(exc)
    except Exception as exc:  # noqa: BLE001 - one recording's bug must not stop the others
        log.debug("%s failed:\n%s", job.input, traceback.format_exc())
        row.failure = f"internal error: {type(exc).__name__}: {exc}"
    row.time_s = time.perf_counter() - t0
    return row


def _failed(job: Job, why: str) -> BatchRow:
    return BatchRow(job.name, job.input, failure=why)


def _thread_env(threads: int) -> dict[str, str]:
    """This process's environment with the thread pools capped to ``threads``."""
    env = dict(os.environ)
    if threads > 0:
        env.update({k: str(threads) for k in THREAD_ENV})
    return env


def _run_in_process(job: Job) -> BatchRow:
    """Run ``job`` in a fresh Python process (``python -m pointrig.batch``) whose thread
    pools are capped to ``job.threads``; a process that dies is a failed row."""
    proc = subprocess.run([sys.executable, "-m", "pointrig.batch"], input=pickle.dumps(job),
                          capture_output=True, env=_thread_env(job.threads), check=False)
    if proc.returncode == 0:
        try:
            row = pickle.loads(proc.stdout)
            if isinstance(row, BatchRow):
                return row
        except Exception:  # noqa: BLE001 - reported as the failure below
            pass
    lines = proc.stderr.decode(errors="replace").strip().splitlines()
    last = f": {lines[-1]}" if lines else ""
    how = (f"signal {-proc.returncode}" if proc.returncode < 0
           else f"exit code {proc.returncode}")
    return _failed(job, f"the worker process ended with {how}{last}")


def _worker_main() -> int:
    """``python -m pointrig.batch``: read a pickled :class:`Job` on stdin, run it, write the
    pickled :class:`BatchRow` on stdout."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    job = pickle.loads(sys.stdin.buffer.read())
    row = run_job(job)
    sys.stdout.buffer.write(pickle.dumps(row))
    sys.stdout.flush()
    return 0


def _dask() -> tuple[Any, Any]:
    """distributed's ``Client`` and ``as_completed`` (:class:`PointrigError` without the
    ``batch`` extra)."""
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise PointrigError(_DASK_EXTRA) from None
    return Client, dask_completed


def _connect(scheduler: str) -> Any:
    """A Dask client of the cluster at ``scheduler`` (:class:`PointrigError` without the
    ``batch`` extra or when the scheduler does not answer within 20 s)."""
    Client, _ = _dask()
    try:
        return Client(scheduler, timeout="20s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise PointrigError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None


def _run_dask(client: Any, jobs: list[Job], done: Callable[[BatchRow], None]
              ) -> dict[str, BatchRow]:
    """Run the jobs on the Dask cluster of ``client``, one task each."""
    _, dask_completed = _dask()
    rows: dict[str, BatchRow] = {}
    tag = uuid.uuid4().hex[:8]
    futures = {client.submit(run_job, job, key=f"pointrig-{job.name}-{tag}", pure=False): job
               for job in jobs}
    for fut in dask_completed(futures):
        job = futures[fut]
        try:
            row = fut.result()
        except Exception as exc:  # noqa: BLE001 - a lost worker fails this job only
            row = _failed(job, f"the Dask task failed: {type(exc).__name__}: {exc}")
        rows[job.name] = row
        done(row)
    return rows


def run_batch(inputs: Sequence[str | Path], out: str | Path,
              options: BatchOptions | None = None, *, jobs: int = 1,
              threads: int | None = None, scheduler: str | None = None,
              done: Callable[[BatchRow], None] | None = None) -> BatchResult:
    """Extract a skeleton from every input into ``out/<name>`` and write the summary.

    Parameters
    ----------
    inputs
        The recordings (anything ``pointrig extract`` reads).
    out
        The batch's output folder: ``out/<name>/`` per recording, ``out/summary.csv``,
        ``out/index.html``.
    options
        Config and reading options shared by every recording.
    jobs
        Recordings at once on this machine (each in its own process when > 1).
    threads
        Threads per recording (default: ``cores // jobs`` on this machine, 1 on a Dask
        cluster; 0 leaves the thread pools as they are).
    scheduler
        Address of a Dask distributed scheduler to run the jobs on instead.
    done
        Called with each row as its recording finishes.

    Raises
    ------
    OutputError
        ``out`` cannot be a writable folder (before any recording runs).
    ConfigError
        No inputs, ``jobs < 1`` or ``threads < 0``.
    PointrigError
        ``scheduler`` given without the ``batch`` extra, or the scheduler cannot be reached.
    """
    options = options or BatchOptions()
    if jobs < 1:
        raise ConfigError(f"--jobs must be at least 1, got {jobs}")
    if threads is not None and threads < 0:
        raise ConfigError(f"--threads must be 0 or more, got {threads}")
    if threads is None:
        threads = 1 if scheduler else max(1, (os.cpu_count() or 1) // jobs)
    client = _connect(scheduler) if scheduler else None  # before anything is made
    try:
        root = check_output_dir(out)
        plan = plan_jobs(inputs, root, options, threads if (scheduler or jobs > 1) else 0)
        rows = _run_all(plan, jobs, client, done or (lambda row: None))
    finally:
        if client is not None:
            client.close()
    ordered = [rows[job.name] for job in plan]
    summary = write_summary_csv(root / "summary.csv", ordered)
    index = write_index_html(root / "index.html", ordered)
    return BatchResult(ordered, summary, index)


def _run_all(plan: list[Job], jobs: int, client: Any, notify: Callable[[BatchRow], None]
             ) -> dict[str, BatchRow]:
    """Run the jobs: on the Dask cluster of ``client``, else ``jobs`` at once here."""
    rows: dict[str, BatchRow] = {}
    if client is not None:
        rows = _run_dask(client, plan, notify)
    elif jobs == 1:
        for job in plan:
            rows[job.name] = run_job(job)
            notify(rows[job.name])
    else:
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            futures = {pool.submit(_run_in_process, job): job for job in plan}
            for fut in as_completed(futures):
                row = fut.result()
                rows[futures[fut].name] = row
                notify(row)
    return rows


def write_summary_csv(path: Path, rows: Sequence[BatchRow]) -> Path:
    """``summary.csv``: recording, input, frames, joints, time_s, warnings (count), failure;
    written atomically."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["recording", "input", "frames", "joints", "time_s", "warnings", "failure"])
        for r in rows:
            w.writerow([r.recording, r.input, "" if r.frames is None else r.frames,
                        "" if r.joints is None else r.joints, f"{r.time_s:.2f}",
                        len(r.warnings), r.failure])
    return path


def write_index_html(path: Path, rows: Sequence[BatchRow]) -> Path:
    """``index.html``: the summary table, each recording linked to its ``report.html``."""
    from .report import write_index

    return write_index(path, HEADER, [r.cells() for r in rows],
                       [f"{r.recording}/report.html" if r.report else None for r in rows])


def format_table(rows: Sequence[BatchRow]) -> str:
    """The summary as an aligned text table (numbers right-aligned)."""
    cells = [list(HEADER)] + [r.cells() for r in rows]
    width = [max(len(c[i]) for c in cells) for i in range(len(HEADER))]
    right = [False, True, True, True, True, False]
    lines = []
    for c in cells:
        parts = [v.rjust(w) if r else v.ljust(w) for v, w, r in zip(c, width, right)]
        lines.append("  ".join(parts).rstrip())
    return "\n".join(lines)


if __name__ == "__main__":
    # the module's own copy (not ``__main__``), so that the row pickles as pointrig.batch's
    from pointrig.batch import _worker_main as _main

    sys.exit(_main())
