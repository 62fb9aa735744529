"""Every public function of the native core, fed extreme coordinates (1e18 m, 1e300 m, all
points identical) and absurd sizes: each returns a finite result or raises a
:class:`pointrig.errors.PointrigError`; none panics or aborts the process.

The oracle is the process itself: a Rust panic crosses into Python as
``pyo3_runtime.PanicException`` (a ``BaseException``, not a ``PointrigError``) and an
allocation failure aborts the interpreter, which the subprocess case below sees as a signal.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from collections.abc import Callable

import numpy as np
import pytest

from pointrig import _core
from pointrig.config import RegistrationConfig
from pointrig.errors import PointrigError
from pointrig.registration import _frame_params

F, M, B = 3, 40, 2


def _calls(pts: Callable[[np.ndarray], np.ndarray]) -> dict[str, Callable[[], object]]:
    """One call per public function of ``_core`` on small valid data whose point arrays
    (metres) went through ``pts``."""
    rng = np.random.default_rng(0)
    q = pts(rng.normal(scale=0.3, size=(M, 3)))
    y = np.ascontiguousarray(np.stack([q + 0.01 * t for t in range(F)]))
    labels = (np.arange(M) % B).astype(np.int64)
    eye = np.tile(np.eye(3), (F, B, 1, 1))
    zero_t = np.zeros((F, B, 3))
    rf = np.ascontiguousarray(eye.reshape(F * B, 9))
    tf = np.zeros((F * B, 3))
    idx = np.stack([labels, 1 - labels], axis=1).astype(np.int64)
    w = np.tile([0.7, 0.3], (M, 1))
    a = np.ones((F, M))
    z = np.ascontiguousarray(y.reshape(-1, 3))
    parent = np.array([-1, 0], np.int64)
    joints = np.ascontiguousarray(q[:B].copy())
    v = np.ascontiguousarray(np.concatenate([q, q]))
    offsets = np.array([0, M, 2 * M], np.int64)
    nodes = np.ascontiguousarray(q[:4].copy())
    graph = lambda: _core.DeformGraph(  # noqa: E731
        q, nodes, np.zeros((M, 1), np.int64), np.ones((M, 1)), np.zeros((0, 2), np.int64))
    params = _frame_params(RegistrationConfig())
    r_nodes = np.tile(np.eye(3), (4, 1, 1))
    return {
        "kabsch": lambda: _core.kabsch(q, q),
        "cluster_fit": lambda: _core.cluster_fit(q, y, labels, B),
        "cluster_residuals": lambda: _core.cluster_residuals(
            q, y, eye, zero_t, labels[:, None].copy()),
        "swap_residuals": lambda: _core.swap_residuals(
            q, y, labels, eye, zero_t, np.array([[0, 1]], np.int64)),
        "lbs_skin": lambda: _core.lbs_skin(q, idx, w, rf, tf, F),
        "lbs_fit_weights": lambda: _core.lbs_fit_weights(q, rf, tf, a, z, F, 2),
        "lbs_sweep_paper": lambda: _core.lbs_sweep_paper(
            q, idx, w, rf, tf, a, z, rf, tf, parent, joints, 1e3, 0.1, F),
        "lbs_sweep_articulated": lambda: _core.lbs_sweep_articulated(
            q, idx, w, rf, tf, a, z, rf, parent, joints, 0.1, F),
        "lbs_estep_frames": lambda: _core.lbs_estep_frames(
            v, v, offsets, np.array([1e-3, 1e-3]), 0.1, 3.0),
        "lbs_joint_normal_sums": lambda: _core.lbs_joint_normal_sums(
            np.ones((M, 2)), a, z),
        "lbs_track_frame": lambda: _core.lbs_track_frame(
            q, labels, parent, joints, v, np.ascontiguousarray(eye[0].reshape(B, 9)),
            (0.0, 0.0, 0.0), 3, 1e-4, 1e-2, 1e-8, 0.5, 0.01, 3.5, 0.1, 1.0),
        "gmm_estep": lambda: _core.gmm_estep(q, q, 1e-3, 0.1, 3.0),
        "gmm_estep_dense": lambda: _core.gmm_estep(q, q, 1e-3, 0.1),
        "surface_normals": lambda: _core.surface_normals(q, q, 0.05),
        "chamfer_misfit": lambda: _core.chamfer_misfit(q, q, 0.1),
        "capped_nn_distances": lambda: _core.capped_nn_distances(q, q, 0.1),
        "capped_nn_distances_grouped": lambda: _core.capped_nn_distances_grouped(
            v, offsets, v, offsets, 0.1),
        "shortest_chord": lambda: _core.shortest_chord(
            np.ascontiguousarray(q[:, :2]), np.zeros(2), np.array([[1.0, 0.0], [0.0, 1.0]]),
            0.5, 1.0),
        "kth_nn_distances": lambda: _core.kth_nn_distances(q, q, 3),
        "farthest_point_sampling": lambda: _core.farthest_point_sampling(q, 10, 0),
        "deform_graph": lambda: graph().deform(r_nodes, np.zeros((4, 3))),
        "register_frame": lambda: graph().register_frame(
            q, r_nodes, np.zeros((4, 3)), params, sigma2_start=1e-2, rigid_iters=2),
    }


def test_every_public_function_is_swept():
    public = {n for n in dir(_core) if not n.startswith("_")} - {"FrameParams"}
    covered = set(_calls(lambda p: p)) | {"DeformGraph", "simplex_qp"}
    assert public <= covered | {"gmm_estep", "deform_graph"}, public - covered


def _finite(out: object) -> bool:
    """Every number in a (nested) result is finite."""
    if isinstance(out, dict):
        return all(_finite(v) for v in out.values())
    if isinstance(out, (tuple, list)):
        return all(_finite(v) for v in out)
    arr = np.asarray(out)
    return not np.issubdtype(arr.dtype, np.number) or bool(np.isfinite(arr).all())


TRANSFORMS = {
    "1e18": lambda p: np.ascontiguousarray(p * 1e18),
    "offset 1e18": lambda p: np.ascontiguousarray(p + 1e18),
    "1e300": lambda p: np.ascontiguousarray(p * 1e300),
    "mixed 1e300": lambda p: np.ascontiguousarray(np.where(np.arange(len(p))[:, None] == 3,
                                                           1e300, p)),
    "identical": lambda p: np.ascontiguousarray(np.zeros_like(p) + 0.5),
}


@pytest.mark.parametrize("case", list(TRANSFORMS))
@pytest.mark.parametrize("name", list(_calls(lambda p: p)))
def test_extreme_coordinates_give_a_result_or_a_pointrig_error(name, case):
    call = _calls(TRANSFORMS[case])[name]
    try:
        out = call()
    except PointrigError:
        return
    except BaseException as exc:  # a panic arrives as a BaseException
        pytest.fail(f"{name} on {case}: {type(exc).__name__}: {exc}")
    if case == "identical":
        assert _finite(out), f"{name} on identical points: non-finite result"


def test_clean_inputs_run():
    """The sweep's calls are valid: on ordinary points every one returns (a check that the
    cases above test the extreme values, not a malformed call)."""
    for name, call in _calls(lambda p: p).items():
        assert _finite(call()), name


ABSURD = """
import numpy as np
from pointrig import _core
from pointrig.errors import PointrigError
q = np.random.default_rng(0).normal(size=(20, 3))
y = np.ascontiguousarray(np.stack([q, q]))
lab = np.zeros(20, np.int64)
cases = {
    "cluster_fit 2**40": lambda: _core.cluster_fit(q, y, lab, 2**40),
    "cluster_fit 2**62": lambda: _core.cluster_fit(q, y, lab, 2**62),
    "farthest_point_sampling 2**62": lambda: _core.farthest_point_sampling(q, 2**62, 0),
    "kth_nn_distances 2**62": lambda: _core.kth_nn_distances(q, q, 2**62),
    "capped_nn_distances_grouped offsets 2**62": lambda: _core.capped_nn_distances_grouped(
        q, np.array([0, 2**62]), q, np.array([0, 20]), 0.1),
    "lbs_fit_weights k 2**40": lambda: _core.lbs_fit_weights(
        q, np.tile(np.eye(3).ravel(), (2, 1)), np.zeros((2, 3)), np.ones((2, 20)),
        np.ascontiguousarray(y.reshape(-1, 3)), 2, 2**40),
    "surface_normals radius 1e-300": lambda: _core.surface_normals(q, q, 1e-300),
    "gmm_estep sigma2 1e-300": lambda: _core.gmm_estep(q, q, 1e-300, 0.1, 3.0),
}
for name, call in cases.items():
    try:
        call()
        print(name, "ok", flush=True)
    except PointrigError as exc:
        print(name, "PointrigError", exc, flush=True)
    except BaseException as exc:
        print(name, "WRONG", type(exc).__name__, exc, flush=True)
"""


def test_absurd_sizes_raise_instead_of_aborting():
    run = subprocess.run([sys.executable, "-c", textwrap.dedent(ABSURD)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, f"the process died ({run.returncode}): {run.stdout}{run.stderr}"
    lines = run.stdout.splitlines()
    assert len(lines) == 8, run.stdout + run.stderr
    assert not [ln for ln in lines if " WRONG " in ln], run.stdout
