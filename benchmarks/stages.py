"""Per-stage wall and CPU seconds of one pipeline run, and the share of each stage spent in
Python code (which holds the interpreter lock, so it runs on one core whatever the pool sizes).

:class:`StageProfile` wraps the pipeline's stage functions (:data:`STAGES`: module, function)
for the length of a ``with`` block and records, per stage, the wall seconds
(``time.perf_counter``) and the process CPU seconds (``time.process_time``: every thread,
Rust's included) spent in it, exclusive of the stages nested in it (step 3's tracking inside
step 3). A stage function called from a worker thread (step 1's candidates' misfit when the
candidates run side by side) counts in the stage that started the thread. Stages run one after
another on the calling thread, so the process CPU time between a
stage's entry and exit is that stage's. Time outside every stage (reading, imports, writing
the pictures) is ``other``.

With ``python=True`` each stage is also run under :mod:`cProfile` timed by each thread's own
CPU clock (``time.thread_time``), on the calling thread and on every thread started during the
stage (the stages' worker pools); the Python seconds of a stage are the summed *own* time of
the Python functions (not of the native calls they make: numpy, Rust), i.e. CPU time of the
interpreter running Python code. The profiler slows Python code down, so those figures are an
upper bound and belong to a separate run from the timed one.
"""

from __future__ import annotations

import cProfile
import functools
import pstats
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import pointrig.joints as joints_mod
import pointrig.pipeline as pipeline_mod
import pointrig.registration as reg_mod
import pointrig.structure as struct_mod

#: ``(stage name, module, function)``: the functions whose calls make each stage, in the
#: order they run
STAGES: tuple[tuple[str, Any, str], ...] = (
    ("clean-up", pipeline_mod, "_clean_input"),
    ("rest candidates", reg_mod, "rest_candidates"),
    ("step 1 registration", reg_mod, "register_sequence"),
    ("candidates' misfit", reg_mod, "sequence_misfit"),
    ("step 2 structure", struct_mod, "extract_structure"),
    ("step 3 tracking", joints_mod, "track_bones"),
    ("step 3 joints", joints_mod, "learn_joints"),
    ("refinement", reg_mod, "refine_registration"),
    ("output skeleton", pipeline_mod, "output_skeleton"),
    ("writing outputs", pipeline_mod, "_write_outputs"),
)
#: the name of the time outside every stage
OTHER = "other"


@dataclass
class StageTimes:
    """Seconds of one stage: ``wall``, process ``cpu``, ``python`` (CPU seconds in Python
    code, profiled runs only) and ``calls``."""

    wall: float = 0.0
    cpu: float = 0.0
    python: float = 0.0
    calls: int = 0


@dataclass
class _Frame:
    """A stage being run: its entry clocks and the inclusive seconds of its nested stages."""

    name: str
    wall0: float
    cpu0: float
    child_wall: float = 0.0
    child_cpu: float = 0.0
    profiles: list[cProfile.Profile] = field(default_factory=list)


def python_seconds(profiles: list[cProfile.Profile]) -> float:
    """Summed own time (seconds of the profiles' clock) of the Python functions of
    ``profiles``, native calls (numpy, Rust, builtins: file ``~``) and this module's wrappers
    left out."""
    total = 0.0
    for prof in profiles:
        prof.create_stats()
        if not prof.stats:  # type: ignore[attr-defined]
            continue
        st = pstats.Stats(prof)
        for (filename, _line, _name), (_cc, _nc, tt, _ct, _callers) in st.stats.items():  # type: ignore[attr-defined]
            if filename not in ("~", __file__):
                total += tt
    return total


class StageProfile:
    """Per-stage seconds of the pipeline runs inside :meth:`recording` (see the module)."""

    def __init__(self, python: bool = False) -> None:
        self.python = python
        self.times: dict[str, StageTimes] = {name: StageTimes() for name, _, _ in STAGES}
        self.total = StageTimes()
        self._stack: list[_Frame] = []
        self._owner: int | None = None

    def _wrap(self, name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            if threading.get_ident() != self._owner:  # a stage called from a worker thread
                return fn(*args, **kwargs)
            self._enter(name)
            try:
                return fn(*args, **kwargs)
            finally:
                self._exit()
        return wrapper

    def _enter(self, name: str) -> None:
        if self.python:
            if self._stack:
                self._stack[-1].profiles[0].disable()
            prof = cProfile.Profile(time.thread_time)
            frame = _Frame(name, 0.0, 0.0, profiles=[prof])
            threading.setprofile(self._bootstrap(frame.profiles))
            prof.enable()
        else:
            frame = _Frame(name, 0.0, 0.0)
        frame.wall0, frame.cpu0 = time.perf_counter(), time.process_time()
        self._stack.append(frame)

    def _exit(self) -> None:
        wall1, cpu1 = time.perf_counter(), time.process_time()
        frame = self._stack.pop()
        wall, cpu = wall1 - frame.wall0, cpu1 - frame.cpu0
        rec = self.times[frame.name]
        rec.wall += wall - frame.child_wall
        rec.cpu += cpu - frame.child_cpu
        rec.calls += 1
        if self._stack:
            self._stack[-1].child_wall += wall
            self._stack[-1].child_cpu += cpu
        if self.python:
            frame.profiles[0].disable()
            threading.setprofile(None)
            rec.python += python_seconds(frame.profiles)
            if self._stack:
                parent = self._stack[-1].profiles
                threading.setprofile(self._bootstrap(parent))
                parent[0].enable()

    @staticmethod
    def _bootstrap(profiles: list[cProfile.Profile]) -> Callable[..., None]:
        """A ``threading.setprofile`` hook: a thread started now gets its own profiler."""
        def hook(_frame: Any, _event: str, _arg: Any) -> None:
            prof = cProfile.Profile(time.thread_time)
            profiles.append(prof)
            prof.enable()
        return hook

    @contextmanager
    def recording(self) -> Iterator[StageProfile]:
        """Record the stages of the pipeline runs in this block (on this thread); the whole
        block's seconds go to :attr:`total`."""
        saved = [(mod, fn, getattr(mod, fn)) for _, mod, fn in STAGES]
        self._owner = threading.get_ident()
        for name, mod, fn in STAGES:
            setattr(mod, fn, self._wrap(name, getattr(mod, fn)))
        wall0, cpu0 = time.perf_counter(), time.process_time()
        try:
            yield self
        finally:
            self.total.wall += time.perf_counter() - wall0
            self.total.cpu += time.process_time() - cpu0
            self.total.calls += 1
            for mod, fn, value in saved:
                setattr(mod, fn, value)

    def other(self) -> StageTimes:
        """The seconds outside every stage."""
        return StageTimes(self.total.wall - sum(t.wall for t in self.times.values()),
                          self.total.cpu - sum(t.cpu for t in self.times.values()))


def table(timed: StageProfile, profiled: StageProfile | None = None,
          reference: StageProfile | None = None, ref_name: str = "reference") -> str:
    """The per-stage table of ``timed``: wall and CPU seconds, CPU / wall, with ``profiled``
    the Python CPU seconds and their share of the stage's wall time (of the profiled run), with
    ``reference`` its wall and CPU and the CPU ratio reference / timed."""
    head = f"{'stage':<22}{'wall s':>9}{'CPU s':>9}{'CPU/wall':>9}"
    if profiled is not None:
        head += f"{'Python s':>10}{'Python %':>10}"
    if reference is not None:
        head += f"{ref_name + ' wall':>16}{ref_name + ' CPU':>15}{'CPU ratio':>10}"
    lines = [head, "-" * len(head)]
    rows = [(name, timed.times[name], None if profiled is None else profiled.times[name],
             None if reference is None else reference.times[name]) for name, _, _ in STAGES]
    rows.append((OTHER, timed.other(), None if profiled is None else profiled.other(),
                 None if reference is None else reference.other()))
    rows.append(("total", timed.total, None if profiled is None else profiled.total,
                 None if reference is None else reference.total))
    for name, t, p, r in rows:
        if name != "total" and t.calls == 0 and name != OTHER and (r is None or r.calls == 0):
            continue
        line = f"{name:<22}{t.wall:9.2f}{t.cpu:9.2f}{t.cpu / max(t.wall, 1e-9):9.2f}"
        if p is not None:
            if name == "total":
                py = sum(x.python for x in profiled.times.values())  # type: ignore[union-attr]
            else:
                py = p.python
            line += f"{py:10.2f}{100 * py / max(p.wall, 1e-9):9.0f}%" if name != OTHER \
                else f"{'':>10}{'':>10}"
        if r is not None:
            line += f"{r.wall:16.2f}{r.cpu:15.2f}{r.cpu / max(t.cpu, 1e-9):9.2f}x"
        lines.append(line)
    return "\n".join(lines)
