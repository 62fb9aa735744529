//! Bindings for step 1, non-rigid registration (§4): the E-step sufficient statistics and
//! the deformation graph (`DeformGraph`) with its M-step solvers and per-frame EM.

// `!(x > 0.0)` deliberately also rejects NaN; PyO3 return tuples are spelled out.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::type_complexity)]

use nalgebra::{Matrix3, Vector3};
use numpy::{
    PyArray1, PyArray2, PyArray3, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyReadonlyArray3, PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::CSlice;
use pyo3::types::PyDict;

use super::{flat1, flat2, input_err, points, to_array2, to_indices, to_pyerr};
use crate::core::deform::{self, DataTerm, FrameParams, Graph, NodeState, Solver, Weights};
use crate::core::error::{check_finite, CoreResult};
use crate::core::gmm::{self, Precision};

/// Node rotations `R (J, 3, 3)`, checked for shape and finiteness.
fn read_rotations(
    py: Python<'_>,
    r: &PyReadonlyArray3<'_, f64>,
    j: usize,
) -> PyResult<Vec<Matrix3<f64>>> {
    let rs = r.shape();
    if rs[0] != j || rs[1] != 3 || rs[2] != 3 {
        return Err(input_err(format!("R must have shape ({j}, 3, 3)")));
    }
    let rsl = r.c_slice("R")?;
    check_finite("R", rsl).map_err(|e| to_pyerr(py, e))?;
    Ok(rsl.chunks_exact(9).map(Matrix3::from_row_slice).collect())
}

fn read_state(
    py: Python<'_>,
    r: &PyReadonlyArray3<'_, f64>,
    t: &PyReadonlyArray2<'_, f64>,
    j: usize,
) -> PyResult<NodeState> {
    let rot = read_rotations(py, r, j)?;
    let tsl = points(py, t, "T")?;
    if tsl.len() != 3 * j {
        return Err(input_err(format!("T must have shape ({j}, 3)")));
    }
    Ok(NodeState {
        r: rot,
        t: tsl
            .chunks_exact(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect(),
    })
}

fn write_state<'py>(
    py: Python<'py>,
    st: &NodeState,
) -> PyResult<(Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<f64>>)> {
    let j = st.r.len();
    let r: Vec<f64> =
        st.r.iter()
            .flat_map(|m| (0..3).flat_map(move |a| (0..3).map(move |b| m[(a, b)])))
            .collect();
    let t: Vec<f64> = st.t.iter().flat_map(|v| [v.x, v.y, v.z]).collect();
    Ok((
        PyArray1::from_vec(py, r).reshape([j, 3, 3])?,
        to_array2(py, t, 3)?,
    ))
}

fn vec_points<'py>(py: Python<'py>, y: &[Vector3<f64>]) -> PyResult<Bound<'py, PyArray2<f64>>> {
    to_array2(py, y.iter().flat_map(|v| [v.x, v.y, v.z]).collect(), 3)
}

/// The embedded deformation graph of Eq. 2 (rest points, nodes, point-node weights,
/// node-node edges of Eq. 6) with the M-step solvers and one-frame EM (Algorithm 1).
#[pyclass(module = "pointrig._core", frozen)]
struct DeformGraph {
    g: Graph,
}

#[pymethods]
impl DeformGraph {
    #[new]
    #[pyo3(signature = (rest, nodes, pn_idx, pn_w, edges, normals=None))]
    fn new(
        py: Python<'_>,
        rest: PyReadonlyArray2<'_, f64>,
        nodes: PyReadonlyArray2<'_, f64>,
        pn_idx: PyReadonlyArray2<'_, i64>,
        pn_w: PyReadonlyArray2<'_, f64>,
        edges: PyReadonlyArray2<'_, i64>,
        normals: Option<PyReadonlyArray2<'_, f64>>,
    ) -> PyResult<Self> {
        let r = points(py, &rest, "rest")?;
        let n = points(py, &nodes, "nodes")?;
        let k = pn_idx.shape()[1];
        let w = flat2(py, &pn_w, "pn_w", k)?;
        let idx = pn_idx.c_slice("pn_idx")?;
        if edges.shape()[1] != 2 {
            return Err(input_err("edges must have shape (E, 2)"));
        }
        let e = edges.c_slice("edges")?;
        let mut g = Graph::new(r, n, idx, w, k, e).map_err(|e| to_pyerr(py, e))?;
        if let Some(nm) = normals {
            let nv = points(py, &nm, "normals")?;
            g.set_normals(nv).map_err(|e| to_pyerr(py, e))?;
        }
        Ok(DeformGraph { g })
    }

    #[getter]
    fn n_nodes(&self) -> usize {
        self.g.n_nodes()
    }
    #[getter]
    fn n_points(&self) -> usize {
        self.g.n_points()
    }
    #[getter]
    fn n_edges(&self) -> usize {
        self.g.n_edges()
    }

    /// Deformed points (Eq. 2), (M, 3).
    fn deform<'py>(
        &self,
        py: Python<'py>,
        r: PyReadonlyArray3<'py, f64>,
        t: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let st = read_state(py, &r, &t, self.g.n_nodes())?;
        let y = py.detach(|| self.g.deform(&st));
        vec_points(py, &y)
    }

    /// Deformed rest normals `normalise(sum_j w R_j n)`, (M, 3); needs the rotations only.
    fn deform_normals<'py>(
        &self,
        py: Python<'py>,
        r: PyReadonlyArray3<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        if !self.g.has_normals() {
            return Err(input_err(
                "deform_normals: the graph was built without normals",
            ));
        }
        let j = self.g.n_nodes();
        let st = NodeState {
            r: read_rotations(py, &r, j)?,
            t: vec![Vector3::zeros(); j],
        };
        let y = py.detach(|| self.g.deform_normals(&st));
        vec_points(py, &y)
    }

    /// Eq. 8a from the E-step statistics.
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (r, t, r_pre, t_pre, p1, px, sum_x2, n_p, sigma2, beta_smooth, beta_small))]
    fn energy(
        &self,
        py: Python<'_>,
        r: PyReadonlyArray3<'_, f64>,
        t: PyReadonlyArray2<'_, f64>,
        r_pre: PyReadonlyArray3<'_, f64>,
        t_pre: PyReadonlyArray2<'_, f64>,
        p1: PyReadonlyArray1<'_, f64>,
        px: PyReadonlyArray2<'_, f64>,
        sum_x2: f64,
        n_p: f64,
        sigma2: f64,
        beta_smooth: f64,
        beta_small: f64,
    ) -> PyResult<f64> {
        let j = self.g.n_nodes();
        let st = read_state(py, &r, &t, j)?;
        let pre = read_state(py, &r_pre, &t_pre, j)?;
        let p1 = self.data(py, &p1, &px)?;
        let d = DataTerm {
            p1: p1.0,
            px: p1.1,
            sum_x2,
            n_p,
            sigma2,
        };
        Ok(self.g.energy(
            &st,
            &pre,
            &d,
            &Weights {
                beta_smooth,
                beta_small,
            },
        ))
    }

    /// The paper's closed-form update of node `j` (Eqs. 9, 11) with the others fixed;
    /// returns the new `(R_j (3, 3), T_j (3,))`.
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (j, r, t, r_pre, t_pre, p1, px, sigma2, beta_smooth, beta_small))]
    fn node_update<'py>(
        &self,
        py: Python<'py>,
        j: usize,
        r: PyReadonlyArray3<'py, f64>,
        t: PyReadonlyArray2<'py, f64>,
        r_pre: PyReadonlyArray3<'py, f64>,
        t_pre: PyReadonlyArray2<'py, f64>,
        p1: PyReadonlyArray1<'py, f64>,
        px: PyReadonlyArray2<'py, f64>,
        sigma2: f64,
        beta_smooth: f64,
        beta_small: f64,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>)> {
        let nj = self.g.n_nodes();
        if j >= nj {
            return Err(input_err(format!("node {j} out of range")));
        }
        let mut st = read_state(py, &r, &t, nj)?;
        let pre = read_state(py, &r_pre, &t_pre, nj)?;
        let (p1s, pxs) = self.data(py, &p1, &px)?;
        if !(sigma2 > 0.0) {
            return Err(input_err("sigma2 must be positive"));
        }
        let d = DataTerm {
            p1: p1s,
            px: pxs,
            sum_x2: 0.0,
            n_p: 0.0,
            sigma2,
        };
        let mut y = self.g.deform(&st);
        self.g.node_update(
            &mut st,
            &pre,
            &mut y,
            j,
            &d,
            &Weights {
                beta_smooth,
                beta_small,
            },
        );
        let rv: Vec<f64> = (0..3)
            .flat_map(|a| (0..3).map(move |b| (a, b)))
            .map(|(a, b)| st.r[j][(a, b)])
            .collect();
        Ok((
            to_array2(py, rv, 3)?,
            PyArray1::from_vec(py, st.t[j].iter().copied().collect()),
        ))
    }

    /// One joint Gauss-Newton step on all nodes; returns the new `(R (J,3,3), T (J,3))`.
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (r, t, p1, px, sigma2, beta_smooth, beta_small, damping=0.0, cg_tol=1e-8, cg_max=500))]
    fn gauss_newton_step<'py>(
        &self,
        py: Python<'py>,
        r: PyReadonlyArray3<'py, f64>,
        t: PyReadonlyArray2<'py, f64>,
        p1: PyReadonlyArray1<'py, f64>,
        px: PyReadonlyArray2<'py, f64>,
        sigma2: f64,
        beta_smooth: f64,
        beta_small: f64,
        damping: f64,
        cg_tol: f64,
        cg_max: usize,
    ) -> PyResult<(Bound<'py, PyArray3<f64>>, Bound<'py, PyArray2<f64>>)> {
        let mut st = read_state(py, &r, &t, self.g.n_nodes())?;
        let (p1s, pxs) = self.data(py, &p1, &px)?;
        if !(sigma2 > 0.0) {
            return Err(input_err("sigma2 must be positive"));
        }
        let d = DataTerm {
            p1: p1s,
            px: pxs,
            sum_x2: 0.0,
            n_p: 0.0,
            sigma2,
        };
        let w = Weights {
            beta_smooth,
            beta_small,
        };
        py.detach(|| {
            self.g
                .gauss_newton_step(&mut st, &d, &w, damping, cg_tol, cg_max)
        });
        write_state(py, &st)
    }

    /// Algorithm 1 on one frame from node transforms `(r, t)` with the sequence's `params`,
    /// starting at `sigma2_start` (m^2) with `rigid_iters` rigid iterations; returns a dict
    /// with `R`, `T`, `points` (M, 3), `sigma2`, `iterations`, `energy`, `n_p`, `n_data`,
    /// `history` (k, 2).
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (x, r, t, params, *, sigma2_start, rigid_iters, x_normals=None))]
    fn register_frame<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
        r: PyReadonlyArray3<'py, f64>,
        t: PyReadonlyArray2<'py, f64>,
        params: &PyFrameParams,
        sigma2_start: f64,
        rigid_iters: usize,
        x_normals: Option<PyReadonlyArray2<'py, f64>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let xs = points(py, &x, "x")?;
        let xn = match &x_normals {
            Some(a) => Some(points(py, a, "x_normals")?),
            None => None,
        };
        let st = read_state(py, &r, &t, self.g.n_nodes())?;
        let p = params.p;
        let res = py
            .detach(|| deform::register_frame(&self.g, st, xs, xn, &p, sigma2_start, rigid_iters))
            .map_err(|e| to_pyerr(py, e))?;
        let d = PyDict::new(py);
        let (r, t) = write_state(py, &res.state)?;
        d.set_item("R", r)?;
        d.set_item("T", t)?;
        d.set_item("points", vec_points(py, &res.points)?)?;
        d.set_item("sigma2", res.sigma2)?;
        d.set_item("iterations", res.iterations)?;
        d.set_item("energy", res.energy)?;
        d.set_item("n_p", res.n_p)?;
        d.set_item("n_data", res.n_data)?;
        let h: Vec<f64> = res.history.iter().flat_map(|&(a, b)| [a, b]).collect();
        d.set_item("history", to_array2(py, h, 2)?)?;
        Ok(d)
    }
}

/// The parameters of `DeformGraph.register_frame` that stay the same for every frame of a
/// sequence (`deform::FrameParams`), built once from `RegistrationConfig`.
#[pyclass(module = "pointrig._core", name = "FrameParams", frozen)]
struct PyFrameParams {
    p: FrameParams,
}

#[pymethods]
impl PyFrameParams {
    #[new]
    #[allow(clippy::too_many_arguments)]
    #[pyo3(signature = (*, omega, beta_smooth, beta_relative, beta_small, sigma2_min, anneal,
        anneal_floor, max_iter, tol, cutoff, solver, damping, cg_tol, cg_max, subsample=0.0,
        motion_tol=0.0, kappa=0.0))]
    fn new(
        omega: f64,
        beta_smooth: f64,
        beta_relative: bool,
        beta_small: f64,
        sigma2_min: f64,
        anneal: f64,
        anneal_floor: f64,
        max_iter: usize,
        tol: f64,
        cutoff: Option<f64>,
        solver: &str,
        damping: f64,
        cg_tol: f64,
        cg_max: usize,
        subsample: f64,
        motion_tol: f64,
        kappa: f64,
    ) -> PyResult<Self> {
        let solver = match solver {
            "gauss_newton" => Solver::GaussNewton,
            "sweeps" => Solver::Sweeps,
            other => {
                return Err(input_err(format!(
                    "solver must be 'gauss_newton' or 'sweeps', got {other:?}"
                )))
            }
        };
        Ok(PyFrameParams {
            p: FrameParams {
                omega,
                beta_smooth,
                beta_relative,
                beta_small,
                sigma2_min,
                anneal,
                anneal_floor,
                max_iter,
                tol,
                cutoff,
                solver,
                damping,
                cg_tol,
                cg_max,
                subsample,
                motion_tol,
                kappa,
            },
        })
    }

    fn __repr__(&self) -> String {
        format!("FrameParams({:?})", self.p)
    }
}

impl DeformGraph {
    fn data<'a>(
        &self,
        py: Python<'_>,
        p1: &'a PyReadonlyArray1<'_, f64>,
        px: &'a PyReadonlyArray2<'_, f64>,
    ) -> PyResult<(&'a [f64], &'a [f64])> {
        let m = self.g.n_points();
        let p1s = flat1(py, p1, "p1")?;
        let pxs = points(py, px, "px")?;
        if p1s.len() != m || pxs.len() != 3 * m {
            return Err(input_err(format!("p1, px must have {m} rows")));
        }
        if p1s.iter().any(|&v| v < 0.0) {
            return Err(input_err("p1 must be non-negative"));
        }
        Ok((p1s, pxs))
    }
}

type EStepOut<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyDict>,
);

/// E-step of Eq. 4 as sufficient statistics (see `_core.pyi`).
#[pyfunction]
#[pyo3(signature = (y, x, sigma2, omega, cutoff=None, single=false))]
fn gmm_estep<'py>(
    py: Python<'py>,
    y: PyReadonlyArray2<'py, f64>,
    x: PyReadonlyArray2<'py, f64>,
    sigma2: f64,
    omega: f64,
    cutoff: Option<f64>,
    single: bool,
) -> PyResult<EStepOut<'py>> {
    let ys = points(py, &y, "y")?;
    let xs = points(py, &x, "x")?;
    let prec = if single {
        Precision::Single
    } else {
        Precision::Double
    };
    let r = py
        .detach(|| gmm::estep(ys, xs, sigma2, omega, cutoff, prec))
        .map_err(|e| to_pyerr(py, e))?;
    let st = r.stats;
    let d = PyDict::new(py);
    d.set_item("n_p", st.n_p)?;
    d.set_item("sum_sq", st.sum_sq)?;
    d.set_item("sum_x2", st.sum_x2)?;
    d.set_item("nll", st.nll)?;
    d.set_item("e_gmm", st.e_gmm)?;
    d.set_item("trunc_bound", st.trunc_bound)?;
    d.set_item("n_pairs", st.n_pairs)?;
    Ok((
        PyArray1::from_vec(py, r.p1),
        PyArray1::from_vec(py, r.pt1),
        to_array2(py, r.px, 3)?,
        d,
    ))
}

/// Camera-facing unit surface normals of `query` from the `source` points within `radius`
/// (see `_core.pyi`).
#[pyfunction]
#[pyo3(signature = (query, source, radius, camera=(0.0, 0.0, 0.0)))]
fn surface_normals<'py>(
    py: Python<'py>,
    query: PyReadonlyArray2<'py, f64>,
    source: PyReadonlyArray2<'py, f64>,
    radius: f64,
    camera: (f64, f64, f64),
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let q = points(py, &query, "query")?;
    let s = points(py, &source, "source")?;
    let cam = [camera.0, camera.1, camera.2];
    let n = py
        .detach(|| crate::core::neighbors::surface_normals(q, s, radius, cam))
        .map_err(|e| to_pyerr(py, e))?;
    to_array2(py, n, 3)
}

/// The symmetric truncated chamfer misfit of a posed template and a frame (see `_core.pyi`).
#[pyfunction]
fn chamfer_misfit(
    py: Python<'_>,
    template: PyReadonlyArray2<'_, f64>,
    data: PyReadonlyArray2<'_, f64>,
    trunc: f64,
) -> PyResult<f64> {
    let t = points(py, &template, "template")?;
    let d = points(py, &data, "data")?;
    py.detach(|| crate::core::nearest::chamfer_misfit(t, d, trunc))
        .map_err(|e| to_pyerr(py, e))
}

/// `(n,)` per-query distances from `queries (n, 3)` to `points_ (N, 3)` by `f`, run without
/// the GIL: the shared body of [`capped_nn_distances`] and [`kth_nn_distances`].
fn query_distances<'py>(
    py: Python<'py>,
    queries: &PyReadonlyArray2<'py, f64>,
    points_: &PyReadonlyArray2<'py, f64>,
    f: impl FnOnce(&[f64], &[f64]) -> CoreResult<Vec<f64>> + Send,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let q = points(py, queries, "queries")?;
    let p = points(py, points_, "points")?;
    let d = py.detach(|| f(q, p)).map_err(|e| to_pyerr(py, e))?;
    Ok(PyArray1::from_vec(py, d))
}

/// Each query's distance to its nearest point, capped (see `_core.pyi`).
#[pyfunction]
fn capped_nn_distances<'py>(
    py: Python<'py>,
    queries: PyReadonlyArray2<'py, f64>,
    points_: PyReadonlyArray2<'py, f64>,
    cap: f64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    query_distances(py, &queries, &points_, |q, p| {
        crate::core::nearest::capped_nn_distances(q, p, cap)
    })
}

/// Each group's queries' distances to the group's nearest point, capped (see `_core.pyi`).
#[pyfunction]
fn capped_nn_distances_grouped<'py>(
    py: Python<'py>,
    queries: PyReadonlyArray2<'py, f64>,
    query_offsets: PyReadonlyArray1<'py, i64>,
    points_: PyReadonlyArray2<'py, f64>,
    point_offsets: PyReadonlyArray1<'py, i64>,
    cap: f64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let q = points(py, &queries, "queries")?;
    let p = points(py, &points_, "points")?;
    let qo = to_indices(query_offsets.c_slice("query_offsets")?, "query_offsets")?;
    let po = to_indices(point_offsets.c_slice("point_offsets")?, "point_offsets")?;
    let d = py
        .detach(|| crate::core::nearest::capped_nn_distances_grouped(q, &qo, p, &po, cap))
        .map_err(|e| to_pyerr(py, e))?;
    Ok(PyArray1::from_vec(py, d))
}

/// Each query's distance to its `k`-th nearest point (see `_core.pyi`).
#[pyfunction]
fn kth_nn_distances<'py>(
    py: Python<'py>,
    queries: PyReadonlyArray2<'py, f64>,
    points_: PyReadonlyArray2<'py, f64>,
    k: usize,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    query_distances(py, &queries, &points_, |q, p| {
        crate::core::nearest::kth_nn_distances(q, p, k)
    })
}

/// Farthest-point sampling indices (see `_core.pyi`).
#[pyfunction]
fn farthest_point_sampling<'py>(
    py: Python<'py>,
    points_: PyReadonlyArray2<'py, f64>,
    n: usize,
    first: usize,
) -> PyResult<Bound<'py, PyArray1<i64>>> {
    let p = points(py, &points_, "points")?;
    let idx = py
        .detach(|| crate::core::nearest::farthest_point_sampling(p, n, first))
        .map_err(|e| to_pyerr(py, e))?;
    Ok(PyArray1::from_vec(
        py,
        idx.into_iter().map(|i| i as i64).collect(),
    ))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(gmm_estep, m)?)?;
    m.add_function(wrap_pyfunction!(surface_normals, m)?)?;
    m.add_function(wrap_pyfunction!(chamfer_misfit, m)?)?;
    m.add_function(wrap_pyfunction!(capped_nn_distances, m)?)?;
    m.add_function(wrap_pyfunction!(capped_nn_distances_grouped, m)?)?;
    m.add_function(wrap_pyfunction!(farthest_point_sampling, m)?)?;
    m.add_function(wrap_pyfunction!(kth_nn_distances, m)?)?;
    m.add_class::<DeformGraph>()?;
    m.add_class::<PyFrameParams>()?;
    Ok(())
}
