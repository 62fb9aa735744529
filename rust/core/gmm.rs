//! E-step of the GMM registration (§4.2, Eq. 4) as sufficient statistics.
//!
//! The template points `y_m` (M, the GMM centroids) and the data points `x_i` (N, the
//! observed `v_i`) define the posteriors of Eq. 4,
//!
//! ```text
//! p_mi = e_mi / (S_i + c0),   e_mi = exp(-|x_i - y_m|^2 / (2 sigma^2)),   S_i = sum_m e_mi,
//! c0   = (2 pi sigma^2)^{3/2} omega M / ((1 - omega) N).
//! ```
//!
//! The M x N matrix is never formed: one pass over the data accumulates
//! `P1 = P 1` (M), `Pt1 = P^T 1` (N), `PX = P X` (M, 3), `N_p`, `sum_mi p_mi |x_i - y_m|^2`
//! (Eq. 12 numerator), `sum_i Pt1_i |x_i|^2` and the negative log-likelihood of Eq. 3.
//!
//! Dense mode visits every pair. Truncated mode (`cutoff = Some(c)`) keeps only pairs with
//! `|x_i - y_m| < c sigma` (found with [`crate::core::neighbors::Grid`]) and reports an a
//! posteriori bound `B >= sum_mi |p~_mi - p_mi|` on the L1 error of the posterior matrix:
//! per data point, with `k_i` kept pairs, `eps = exp(-c^2/2)`,
//! `sum_m |p~_mi - p_mi| <= min(2, 2 (M - k_i) eps / (S~_i + c0))`.
//!
//! Determinism: data points are split into chunks whose size depends only on N; chunk
//! partial sums are reduced in chunk order, so results are bitwise identical for any number
//! of threads. `exp` is a polynomial with Cody-Waite reduction (relative error ~1e-16 in
//! double, ~2e-7 in single) that returns exactly 0 below `EXP_FLOOR_*` (`e^-60` ~ 9e-27 in
//! single, `e^-600` ~ 3e-261 in double). The floors sit far enough above the normal range
//! that no product of the kernels (`e * inv * x`) becomes subnormal: a subnormal operand costs
//! ~100 cycles (a floor at the underflow limit would slow the dense f32 kernel down several
//! times whenever sigma is a few centimetres). The floor changes a posterior row by
//! at most `2 M e^-60 / c0` in L1 (below 1e-12 for sigma >= 1 mm, M <= 1e5); the truncation
//! bound below does not count it.

#![allow(clippy::needless_range_loop)]

use rayon::prelude::*;
use std::ops::{Add, Mul, Sub};

use crate::core::error::{CoreError, CoreResult};
use crate::core::neighbors::Grid;

/// Arithmetic used by the inner loops.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    /// float64 throughout (oracle-exact, ~1e-15 relative).
    Double,
    /// float32 distances, exponentials and per-chunk sums; float64 reductions (~1e-6 relative).
    Single,
}

/// Scalar statistics of one E-step (all in float64, metres).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EStepStats {
    /// `N_p = sum_mi p_mi` (Eq. 5b).
    pub n_p: f64,
    /// `sum_mi p_mi |x_i - y_m|^2`, m^2 (numerator of Eq. 12, y = the input template).
    pub sum_sq: f64,
    /// `sum_i Pt1_i |x_i|^2`, m^2 (constant of the data term when y moves).
    pub sum_x2: f64,
    /// Negative log-likelihood of Eq. 3 at the input `y`, `sigma2`.
    pub nll: f64,
    /// `E_GMM` of Eq. 5b at the input `y`: `sum_sq / (2 sigma^2) + (D N_p / 2) log sigma^2`.
    pub e_gmm: f64,
    /// A posteriori bound on `sum_mi |p~_mi - p_mi|` (0 in dense mode).
    pub trunc_bound: f64,
    /// Number of (m, i) pairs evaluated.
    pub n_pairs: u64,
}

/// Sufficient statistics of one E-step.
#[derive(Debug, Clone, Default)]
pub struct EStep {
    /// `P1_m = sum_i p_mi`, (M,).
    pub p1: Vec<f64>,
    /// `Pt1_i = sum_m p_mi`, (N,).
    pub pt1: Vec<f64>,
    /// `PX_m = sum_i p_mi x_i`, (M, 3) row-major, metres.
    pub px: Vec<f64>,
    pub stats: EStepStats,
}

/// `exp_neg` returns exactly 0 below this (f64; see the module docs).
pub const EXP_FLOOR_F64: f64 = -600.0;
/// `exp_neg` returns exactly 0 below this (f32; see the module docs).
pub const EXP_FLOOR_F32: f32 = -60.0;

/// Inner-loop scalar (f32 or f64).
pub trait Real:
    Copy
    + Send
    + Sync
    + Default
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
{
    const ZERO: Self;
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
    /// `self * a + b` (fused where the CPU has FMA).
    fn fma(self, a: Self, b: Self) -> Self;
    /// `exp(x)` for `x <= 0`; exactly 0 below the type's `EXP_FLOOR_*` (no subnormals).
    fn exp_neg(x: Self) -> Self;
}

impl Real for f64 {
    const ZERO: f64 = 0.0;
    #[inline(always)]
    fn from_f64(v: f64) -> f64 {
        v
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn fma(self, a: f64, b: f64) -> f64 {
        self.mul_add(a, b)
    }
    #[inline(always)]
    fn exp_neg(x: f64) -> f64 {
        const LOW: f64 = EXP_FLOOR_F64;
        const LOG2E: f64 = std::f64::consts::LOG2_E;
        const LN2_HI: f64 = f64::from_bits(0x3fe6_2e42_fee0_0000);
        const LN2_LO: f64 = f64::from_bits(0x3dea_39ef_3579_3c76);
        const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 * 2^52
        let xc = if x < LOW { LOW } else { x };
        let t = xc.mul_add(LOG2E, MAGIC);
        let kf = t - MAGIC;
        let k = (t.to_bits() as i64).wrapping_sub(MAGIC.to_bits() as i64);
        let r = (-kf).mul_add(LN2_LO, (-kf).mul_add(LN2_HI, xc));
        // Taylor to r^13 / 13!, |r| <= ln2 / 2: truncation error < 2e-17 relative.
        let mut p: f64 = 1.0 / 6_227_020_800.0;
        p = p.mul_add(r, 1.0 / 479_001_600.0);
        p = p.mul_add(r, 1.0 / 39_916_800.0);
        p = p.mul_add(r, 1.0 / 3_628_800.0);
        p = p.mul_add(r, 1.0 / 362_880.0);
        p = p.mul_add(r, 1.0 / 40_320.0);
        p = p.mul_add(r, 1.0 / 5_040.0);
        p = p.mul_add(r, 1.0 / 720.0);
        p = p.mul_add(r, 1.0 / 120.0);
        p = p.mul_add(r, 1.0 / 24.0);
        p = p.mul_add(r, 1.0 / 6.0);
        p = p.mul_add(r, 0.5);
        p = p.mul_add(r, 1.0);
        p = p.mul_add(r, 1.0);
        let scale = f64::from_bits(((k + 1023) as u64) << 52);
        if x < LOW {
            0.0
        } else {
            p * scale
        }
    }
}

impl Real for f32 {
    const ZERO: f32 = 0.0;
    #[inline(always)]
    fn from_f64(v: f64) -> f32 {
        v as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn fma(self, a: f32, b: f32) -> f32 {
        self.mul_add(a, b)
    }
    #[inline(always)]
    fn exp_neg(x: f32) -> f32 {
        const LOW: f32 = EXP_FLOOR_F32;
        const LOG2E: f32 = std::f32::consts::LOG2_E;
        const LN2_HI: f32 = 0.693_145_75;
        const LN2_LO: f32 = 1.428_606_8e-6;
        const MAGIC: f32 = 12_582_912.0; // 1.5 * 2^23
        let xc = if x < LOW { LOW } else { x };
        let t = xc.mul_add(LOG2E, MAGIC);
        let kf = t - MAGIC;
        let k = (t.to_bits() as i32).wrapping_sub(MAGIC.to_bits() as i32);
        let r = (-kf).mul_add(LN2_LO, (-kf).mul_add(LN2_HI, xc));
        let mut p: f32 = 1.0 / 720.0;
        p = p.mul_add(r, 1.0 / 120.0);
        p = p.mul_add(r, 1.0 / 24.0);
        p = p.mul_add(r, 1.0 / 6.0);
        p = p.mul_add(r, 0.5);
        p = p.mul_add(r, 1.0);
        p = p.mul_add(r, 1.0);
        let scale = f32::from_bits(((k + 127) as u32) << 23);
        if x < LOW {
            0.0
        } else {
            p * scale
        }
    }
}

/// Template in structure-of-arrays form, centred, in the order used by the accumulators.
struct Template<T> {
    yx: Vec<T>,
    yy: Vec<T>,
    yz: Vec<T>,
    /// Scaled normals `s n~_m` (empty without normals; see [`estep_normals`]).
    nx: Vec<T>,
    ny: Vec<T>,
    nz: Vec<T>,
}

/// Per-chunk partial sums (accumulators in template order of `Template`).
struct Partial<T> {
    p1: Vec<T>,
    px: Vec<T>,
    py: Vec<T>,
    pz: Vec<T>,
    pt1: Vec<f64>,
    sum_sq: f64,
    log_den: f64,
    bound: f64,
    n_pairs: u64,
}

impl<T: Real> Partial<T> {
    fn new(m: usize, n: usize) -> Self {
        Partial {
            p1: vec![T::ZERO; m],
            px: vec![T::ZERO; m],
            py: vec![T::ZERO; m],
            pz: vec![T::ZERO; m],
            pt1: vec![0.0; n],
            sum_sq: 0.0,
            log_den: 0.0,
            bound: 0.0,
            n_pairs: 0,
        }
    }
}

const LANES: usize = 8;
/// The truncated kernel runs while a query's 3 x 3 x 3 cell block holds on average fewer than
/// this share of the template ([`Grid::mean_block`]); with wider cutoffs the exact dense kernel
/// is as fast (measured on a 2-core machine, M = 2000, N = 11k body scan: at a 53 % share the
/// truncated kernel took 8.7 ms and the dense one 9.8 ms).
const DENSE_BLOCK_FRACTION: f64 = 0.6;
const BLOCK: usize = 4;

/// `|(x, y, z) - q|^2` with fused multiply-adds (the kernels' one distance formula).
#[inline(always)]
fn dist2<T: Real>(x: T, y: T, z: T, q: [T; 3]) -> T {
    let dx = x - q[0];
    let dy = y - q[1];
    let dz = z - q[2];
    dx.fma(dx, dy.fma(dy, dz * dz))
}

/// `e[m] = exp(-(|y_m - q|^2 + NRM |s n~_m - s n_q|^2) inv2s)` (`d2` is scratch, the
/// position part only); returns `(sum_m e, sum_m e d^2)`.
#[inline(always)]
fn exp_row<T: Real, const NRM: bool>(
    tpl: &Template<T>,
    q: [T; 3],
    qn: [T; 3],
    inv2s: T,
    e: &mut [T],
    d2: &mut [T],
) -> (f64, f64) {
    let m = tpl.yx.len();
    let e = &mut e[..m];
    let d2 = &mut d2[..m];
    for (((d, &x), &y), &z) in d2.iter_mut().zip(&tpl.yx).zip(&tpl.yy).zip(&tpl.yz) {
        *d = dist2(x, y, z, q);
    }
    if NRM {
        let (nx, ny, nz) = (&tpl.nx[..m], &tpl.ny[..m], &tpl.nz[..m]);
        for ((((o, &d), &a), &b), &c) in e.iter_mut().zip(d2.iter()).zip(nx).zip(ny).zip(nz) {
            *o = T::exp_neg(T::ZERO - (d + dist2(a, b, c, qn)) * inv2s);
        }
    } else {
        for (o, &d) in e.iter_mut().zip(d2.iter()) {
            *o = T::exp_neg(T::ZERO - d * inv2s);
        }
    }
    lane_sums(e, d2)
}

/// `(sum_k e_k, sum_k e_k d2_k)` in `LANES` independent accumulators (so that the loop
/// vectorises), reduced in float64.
#[inline(always)]
fn lane_sums<T: Real>(e: &[T], d2: &[T]) -> (f64, f64) {
    let mut s = [T::ZERO; LANES];
    let mut w = [T::ZERO; LANES];
    let (ec, er) = e.as_chunks::<LANES>();
    let (dc, dr) = d2.as_chunks::<LANES>();
    for (ex, dd) in ec.iter().zip(dc) {
        for l in 0..LANES {
            s[l] = s[l] + ex[l];
            w[l] = ex[l].fma(dd[l], w[l]);
        }
    }
    let mut ss = 0.0;
    let mut ww = 0.0;
    for l in 0..LANES {
        ss += s[l].to_f64();
        ww += w[l].to_f64();
    }
    for (&ek, &dk) in er.iter().zip(dr) {
        ss += ek.to_f64();
        ww += (ek * dk).to_f64();
    }
    (ss, ww)
}

/// Add the posteriors of a block of `BLOCK` data points, `a_b = e_b * inv_b`, to the
/// per-template accumulators: `p1 += sum_b a_b`, `p{x,y,z} += sum_b a_b q_b`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn accumulate_block<T: Real>(
    e: [&[T]; BLOCK],
    inv: [T; BLOCK],
    q: [[T; 3]; BLOCK],
    p1: &mut [T],
    px: &mut [T],
    py: &mut [T],
    pz: &mut [T],
) {
    let n = p1.len();
    let (e0, e1, e2, e3) = (&e[0][..n], &e[1][..n], &e[2][..n], &e[3][..n]);
    let (px, py, pz) = (&mut px[..n], &mut py[..n], &mut pz[..n]);
    let (i0v, i1v, i2v, i3v) = (inv[0], inv[1], inv[2], inv[3]);
    let (q0, q1, q2, q3) = (q[0], q[1], q[2], q[3]);
    for k in 0..n {
        let a0 = e0[k] * i0v;
        let a1 = e1[k] * i1v;
        let a2 = e2[k] * i2v;
        let a3 = e3[k] * i3v;
        p1[k] = p1[k] + ((a0 + a1) + (a2 + a3));
        px[k] = px[k] + ((a0 * q0[0] + a1 * q1[0]) + (a2 * q2[0] + a3 * q3[0]));
        py[k] = py[k] + ((a0 * q0[1] + a1 * q1[1]) + (a2 * q2[1] + a3 * q3[1]));
        pz[k] = pz[k] + ((a0 * q0[2] + a1 * q1[2]) + (a2 * q2[2] + a3 * q3[2]));
    }
}

/// Dense E-step over data points `xs` (centred, flat f64) with global index offset; `xn`
/// holds their scaled normals when `NRM` (else it is empty).
#[inline(always)]
fn dense_chunk<T: Real, const NRM: bool>(
    tpl: &Template<T>,
    xs: &[f64],
    xn: &[f64],
    ws: Option<&[f64]>,
    inv2s: T,
    c0: f64,
) -> Partial<T> {
    let m = tpl.yx.len();
    let n = xs.len() / 3;
    let mut part = Partial::<T>::new(m, n);
    let mut e = vec![T::ZERO; BLOCK * m];
    let mut d2 = vec![T::ZERO; m];
    let mut i0 = 0;
    while i0 < n {
        let nb = BLOCK.min(n - i0);
        let mut inv = [T::ZERO; BLOCK];
        let mut q = [[T::ZERO; 3]; BLOCK];
        for b in 0..nb {
            let i = i0 + b;
            q[b] = [
                T::from_f64(xs[3 * i]),
                T::from_f64(xs[3 * i + 1]),
                T::from_f64(xs[3 * i + 2]),
            ];
            let qn = query_normal::<T, NRM>(xn, i);
            let (s, w) =
                exp_row::<T, NRM>(tpl, q[b], qn, inv2s, &mut e[b * m..(b + 1) * m], &mut d2);
            let den = s + c0;
            let wi = ws.map_or(1.0, |v| v[i]);
            if den > 0.0 {
                inv[b] = T::from_f64(wi / den);
                part.pt1[i] = wi * s / den;
                part.sum_sq += wi * w / den;
                part.log_den += wi * den.ln();
            } else {
                part.log_den += f64::NEG_INFINITY;
            }
        }
        for b in nb..BLOCK {
            e[b * m..(b + 1) * m].fill(T::ZERO);
        }
        let (e0, rest) = e.split_at(m);
        let (e1, rest) = rest.split_at(m);
        let (e2, e3) = rest.split_at(m);
        accumulate_block(
            [e0, e1, e2, e3],
            inv,
            q,
            &mut part.p1[..m],
            &mut part.px[..m],
            &mut part.py[..m],
            &mut part.pz[..m],
        );
        part.n_pairs += (nb * m) as u64;
        i0 += nb;
    }
    part
}

/// The scaled normal of data point `i` (zeros without normals).
#[inline(always)]
fn query_normal<T: Real, const NRM: bool>(xn: &[f64], i: usize) -> [T; 3] {
    if NRM {
        [
            T::from_f64(xn[3 * i]),
            T::from_f64(xn[3 * i + 1]),
            T::from_f64(xn[3 * i + 2]),
        ]
    } else {
        [T::ZERO; 3]
    }
}

/// Candidate template points of one group of queries, gathered contiguously (structure of
/// arrays, padded to a multiple of `LANES`), with per-candidate accumulators.
struct Gather<T> {
    x: Vec<T>,
    y: Vec<T>,
    z: Vec<T>,
    /// Scaled normals (used with normals only).
    nx: Vec<T>,
    ny: Vec<T>,
    nz: Vec<T>,
    /// Template index (sorted order) of each candidate.
    idx: Vec<u32>,
    p1: Vec<T>,
    px: Vec<T>,
    py: Vec<T>,
    pz: Vec<T>,
}

impl<T: Real> Gather<T> {
    fn new(m: usize) -> Self {
        let cap = m + LANES;
        Gather {
            x: vec![T::ZERO; cap],
            y: vec![T::ZERO; cap],
            z: vec![T::ZERO; cap],
            nx: vec![T::ZERO; cap],
            ny: vec![T::ZERO; cap],
            nz: vec![T::ZERO; cap],
            idx: vec![0; cap],
            p1: vec![T::ZERO; cap],
            px: vec![T::ZERO; cap],
            py: vec![T::ZERO; cap],
            pz: vec![T::ZERO; cap],
        }
    }

    /// Copy the template ranges in and clear the accumulators; returns the number of
    /// candidates `n` and the padded length (a multiple of `LANES`; the padding sits at
    /// `far`, beyond any cutoff, so it gets weight 0).
    #[inline(always)]
    fn fill<const NRM: bool>(
        &mut self,
        tpl: &Template<T>,
        ranges: &[(u32, u32)],
        far: T,
    ) -> (usize, usize) {
        // Element loops, not copy_from_slice: the ranges are a few points long and a memmove
        // call per range costs more than the copy.
        let (gx, gy, gz, gi) = (&mut self.x, &mut self.y, &mut self.z, &mut self.idx);
        let mut off = 0;
        for &(lo, hi) in ranges {
            let (a, b) = (lo as usize, hi as usize);
            let end = off + (b - a);
            for (d, &s) in gx[off..end].iter_mut().zip(&tpl.yx[a..b]) {
                *d = s;
            }
            for (d, &s) in gy[off..end].iter_mut().zip(&tpl.yy[a..b]) {
                *d = s;
            }
            for (d, &s) in gz[off..end].iter_mut().zip(&tpl.yz[a..b]) {
                *d = s;
            }
            for (d, k) in gi[off..end].iter_mut().zip(lo..hi) {
                *d = k;
            }
            if NRM {
                self.nx[off..end].copy_from_slice(&tpl.nx[a..b]);
                self.ny[off..end].copy_from_slice(&tpl.ny[a..b]);
                self.nz[off..end].copy_from_slice(&tpl.nz[a..b]);
            }
            off = end;
        }
        let padded = off.div_ceil(LANES) * LANES;
        for j in off..padded {
            gx[j] = far;
            gy[j] = far;
            gz[j] = far;
        }
        self.p1[..padded].fill(T::ZERO);
        self.px[..padded].fill(T::ZERO);
        self.py[..padded].fill(T::ZERO);
        self.pz[..padded].fill(T::ZERO);
        (off, padded)
    }

    /// `e_j = exp(-d_j^2 inv2s)` over the first `len` candidates (a multiple of `LANES`),
    /// zero where `d_j^2 >= r2`; `d2` is scratch. Returns `(sum_j e_j, sum_j e_j d_j^2,
    /// number kept)`. Branch-free so that it vectorises.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn eval<const NRM: bool>(
        &self,
        len: usize,
        q: [T; 3],
        qn: [T; 3],
        inv2s: T,
        r2: T,
        e: &mut [T],
        d2: &mut [T],
    ) -> (f64, f64, usize) {
        let e = &mut e[..len];
        let d2 = &mut d2[..len];
        let (xs, ys, zs) = (&self.x[..len], &self.y[..len], &self.z[..len]);
        for (((d, &x), &y), &z) in d2.iter_mut().zip(xs).zip(ys).zip(zs) {
            *d = dist2(x, y, z, q);
        }
        let mut kept = 0usize;
        if NRM {
            let (nx, ny, nz) = (&self.nx[..len], &self.ny[..len], &self.nz[..len]);
            for ((((o, &d), &a), &b), &c) in e.iter_mut().zip(d2.iter()).zip(nx).zip(ny).zip(nz) {
                let v = T::exp_neg(T::ZERO - (d + dist2(a, b, c, qn)) * inv2s);
                let keep = d < r2;
                kept += keep as usize;
                *o = if keep { v } else { T::ZERO };
            }
        } else {
            for (o, &d) in e.iter_mut().zip(d2.iter()) {
                let v = T::exp_neg(T::ZERO - d * inv2s);
                let keep = d < r2;
                kept += keep as usize;
                *o = if keep { v } else { T::ZERO };
            }
        }
        let (ss, ww) = lane_sums(e, d2);
        (ss, ww, kept)
    }
}

/// Truncated E-step: only pairs closer than `radius` (grid over the template, sorted order).
///
/// The data points of a chunk arrive sorted by [`Grid::key`], so consecutive points share
/// their 3 x 3 x 3 cell block. Per group the block's template points are gathered once into
/// contiguous buffers; then, as in the dense kernel, blocks of `BLOCK` points are evaluated
/// branch-free against the gathered candidates (pairs beyond `radius` get weight 0) and
/// their posteriors summed into per-candidate accumulators, which are added back to the
/// template's at the end of the group.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn truncated_chunk<T: Real, const NRM: bool>(
    tpl: &Template<T>,
    grid: &Grid,
    xs: &[f64],
    xn: &[f64],
    keys: &[u64],
    ws: Option<&[f64]>,
    inv2s: T,
    c0: f64,
    radius: f64,
    eps: f64,
) -> Partial<T> {
    let m = tpl.yx.len();
    let n = xs.len() / 3;
    let cap = m + LANES;
    let mut part = Partial::<T>::new(m, n);
    let r2 = T::from_f64(radius * radius);
    let mut g = Gather::<T>::new(m);
    let mut e = vec![T::ZERO; BLOCK * cap];
    let mut d2 = vec![T::ZERO; cap];
    // Padding coordinate: far beyond the cutoff from any centred query, finite in f32.
    let far = T::from_f64(1e6);
    let mut i0 = 0;
    while i0 < n {
        let key = keys[i0];
        let mut i1 = i0 + 1;
        while i1 < n && keys[i1] == key {
            i1 += 1;
        }
        let (len, padded) = if key == u64::MAX {
            g.fill::<NRM>(tpl, &[], far)
        } else {
            let (ranges, nr) = grid.block([xs[3 * i0], xs[3 * i0 + 1], xs[3 * i0 + 2]]);
            g.fill::<NRM>(tpl, &ranges[..nr], far)
        };
        let mut b0 = i0;
        while b0 < i1 {
            let nb = BLOCK.min(i1 - b0);
            let mut inv = [T::ZERO; BLOCK];
            let mut q = [[T::ZERO; 3]; BLOCK];
            for b in 0..nb {
                let i = b0 + b;
                q[b] = [
                    T::from_f64(xs[3 * i]),
                    T::from_f64(xs[3 * i + 1]),
                    T::from_f64(xs[3 * i + 2]),
                ];
                let qn = query_normal::<T, NRM>(xn, i);
                let eb = &mut e[b * cap..b * cap + padded];
                let (s, w, kept) = g.eval::<NRM>(padded, q[b], qn, inv2s, r2, eb, &mut d2);
                let den = s + c0;
                let dropped = (m - kept) as f64;
                let wi = ws.map_or(1.0, |v| v[i]);
                if den > 0.0 {
                    let invd = 1.0 / den;
                    inv[b] = T::from_f64(wi * invd);
                    part.pt1[i] = wi * s * invd;
                    part.sum_sq += wi * w * invd;
                    part.log_den += wi * den.ln();
                    part.bound += wi * (2.0 * dropped * eps * invd).min(2.0);
                } else {
                    part.log_den += f64::NEG_INFINITY;
                    part.bound += if dropped > 0.0 { 2.0 * wi } else { 0.0 };
                }
            }
            for b in nb..BLOCK {
                e[b * cap..b * cap + padded].fill(T::ZERO);
            }
            let (e0, rest) = e.split_at(cap);
            let (e1, rest) = rest.split_at(cap);
            let (e2, e3) = rest.split_at(cap);
            accumulate_block(
                [e0, e1, e2, e3],
                inv,
                q,
                &mut g.p1[..padded],
                &mut g.px[..padded],
                &mut g.py[..padded],
                &mut g.pz[..padded],
            );
            part.n_pairs += (nb * len) as u64;
            b0 += nb;
        }
        for j in 0..len {
            let k = g.idx[j] as usize;
            part.p1[k] = part.p1[k] + g.p1[j];
            part.px[k] = part.px[k] + g.px[j];
            part.py[k] = part.py[k] + g.py[j];
            part.pz[k] = part.pz[k] + g.pz[j];
        }
        i0 = i1;
    }
    part
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn dense_chunk_avx2<T: Real, const NRM: bool>(
    tpl: &Template<T>,
    xs: &[f64],
    xn: &[f64],
    ws: Option<&[f64]>,
    inv2s: T,
    c0: f64,
) -> Partial<T> {
    dense_chunk::<T, NRM>(tpl, xs, xn, ws, inv2s, c0)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn truncated_chunk_avx2<T: Real, const NRM: bool>(
    tpl: &Template<T>,
    grid: &Grid,
    xs: &[f64],
    xn: &[f64],
    keys: &[u64],
    ws: Option<&[f64]>,
    inv2s: T,
    c0: f64,
    radius: f64,
    eps: f64,
) -> Partial<T> {
    truncated_chunk::<T, NRM>(tpl, grid, xs, xn, keys, ws, inv2s, c0, radius, eps)
}

fn has_avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[allow(clippy::too_many_arguments)]
fn truncated_dispatch<T: Real, const NRM: bool>(
    tpl: &Template<T>,
    grid: &Grid,
    xs: &[f64],
    xn: &[f64],
    keys: &[u64],
    ws: Option<&[f64]>,
    inv2s: T,
    c0: f64,
    radius: f64,
    eps: f64,
) -> Partial<T> {
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU supports the enabled features (checked just above).
            return unsafe {
                truncated_chunk_avx2::<T, NRM>(tpl, grid, xs, xn, keys, ws, inv2s, c0, radius, eps)
            };
        }
    }
    truncated_chunk::<T, NRM>(tpl, grid, xs, xn, keys, ws, inv2s, c0, radius, eps)
}

fn dense_dispatch<T: Real, const NRM: bool>(
    tpl: &Template<T>,
    xs: &[f64],
    xn: &[f64],
    ws: Option<&[f64]>,
    inv2s: T,
    c0: f64,
) -> Partial<T> {
    #[cfg(target_arch = "x86_64")]
    {
        if has_avx2_fma() {
            // SAFETY: the CPU supports the enabled features (checked just above).
            return unsafe { dense_chunk_avx2::<T, NRM>(tpl, xs, xn, ws, inv2s, c0) };
        }
    }
    dense_chunk::<T, NRM>(tpl, xs, xn, ws, inv2s, c0)
}

/// Data points per chunk: depends on N only (determinism across thread counts).
fn chunk_len(n: usize) -> usize {
    256usize.max(n.div_ceil(16))
}

fn validate(y: &[f64], x: &[f64], sigma2: f64, omega: f64, cutoff: Option<f64>) -> CoreResult<()> {
    if !y.len().is_multiple_of(3) || !x.len().is_multiple_of(3) {
        return Err(CoreError::InvalidInput(
            "points must have shape (n, 3)".into(),
        ));
    }
    if y.is_empty() || x.is_empty() {
        return Err(CoreError::InvalidInput(
            "E-step needs at least one template and one data point".into(),
        ));
    }
    if !(sigma2.is_finite() && sigma2 > 0.0) {
        return Err(CoreError::InvalidInput(format!(
            "sigma2 must be positive and finite, got {sigma2}"
        )));
    }
    if !(omega.is_finite() && (0.0..1.0).contains(&omega)) {
        return Err(CoreError::InvalidInput(format!(
            "omega must be in [0, 1), got {omega}"
        )));
    }
    if let Some(c) = cutoff {
        if !(c.is_finite() && c > 0.0) {
            return Err(CoreError::InvalidInput(format!(
                "cutoff must be positive and finite, got {c}"
            )));
        }
    }
    Ok(())
}

/// Unit surface normals of the template and the data for [`estep_normals`].
#[derive(Debug, Clone, Copy)]
pub struct Normals<'a> {
    /// Template normals `n~_m`, flat `(M, 3)`, unit length.
    pub y: &'a [f64],
    /// Data normals `n_i`, flat `(N, 3)`, unit length (or zero: no orientation information).
    pub x: &'a [f64],
    /// Concentration `kappa` of the von Mises-Fisher factor (> 0).
    pub kappa: f64,
}

/// The kernels over all data chunks; returns the partial sums in chunk order and the data
/// order used (empty: input order).
#[allow(clippy::too_many_arguments)]
fn chunks<T: Real, const NRM: bool>(
    tpl: &Template<T>,
    grid: Option<&(Grid, f64, f64)>,
    xc: &[f64],
    xn: &[f64],
    wx: Option<&[f64]>,
    inv2s: T,
    c0: f64,
) -> (Vec<Partial<T>>, Vec<usize>) {
    let n = xc.len() / 3;
    let cl = chunk_len(n);
    // the normals of chunk `ci` (`len` points) of `v` (empty without normals)
    fn nrm<const NRM: bool>(v: &[f64], ci: usize, cl: usize, len: usize) -> &[f64] {
        if NRM {
            &v[3 * ci * cl..3 * (ci * cl + len)]
        } else {
            &[]
        }
    }
    match grid {
        None => {
            let parts = xc
                .par_chunks(3 * cl)
                .enumerate()
                .map(|(ci, xs)| {
                    let len = xs.len() / 3;
                    let ws = wx.map(|w| &w[ci * cl..ci * cl + len]);
                    dense_dispatch::<T, NRM>(tpl, xs, nrm::<NRM>(xn, ci, cl, len), ws, inv2s, c0)
                })
                .collect();
            (parts, Vec::new())
        }
        Some((g, radius, eps)) => {
            // Data sorted by grid key (ties by index: deterministic), so that consecutive
            // points share their cell block; Pt1 is put back in input order by the caller.
            let mut keyed: Vec<(u64, u32)> = xc
                .par_chunks_exact(3)
                .enumerate()
                .map(|(i, p)| (g.key([p[0], p[1], p[2]]), i as u32))
                .collect();
            // (key, index) pairs are distinct, so the sorted order is unique.
            keyed.par_sort_unstable();
            let perm: Vec<usize> = keyed.iter().map(|&(_, i)| i as usize).collect();
            let keys: Vec<u64> = keyed.iter().map(|&(k, _)| k).collect();
            let gather = |v: &[f64]| -> Vec<f64> {
                perm.iter()
                    .flat_map(|&i| [v[3 * i], v[3 * i + 1], v[3 * i + 2]])
                    .collect()
            };
            let xs_sorted = gather(xc);
            let xn_sorted = if NRM { gather(xn) } else { Vec::new() };
            let ws_sorted: Option<Vec<f64>> = wx.map(|w| perm.iter().map(|&i| w[i]).collect());
            let parts = xs_sorted
                .par_chunks(3 * cl)
                .zip(keys.par_chunks(cl))
                .enumerate()
                .map(|(ci, (xs, ks))| {
                    let len = xs.len() / 3;
                    let ws = ws_sorted.as_ref().map(|w| &w[ci * cl..ci * cl + len]);
                    let xn = nrm::<NRM>(&xn_sorted, ci, cl, len);
                    truncated_dispatch::<T, NRM>(tpl, g, xs, xn, ks, ws, inv2s, c0, *radius, *eps)
                })
                .collect();
            (parts, perm)
        }
    }
}

fn validate_weights(x: &[f64], wx: Option<&[f64]>) -> CoreResult<()> {
    if let Some(w) = wx {
        if w.len() * 3 != x.len() || !w.iter().all(|v| v.is_finite() && *v >= 0.0) {
            return Err(CoreError::InvalidInput(
                "data weights must be N finite non-negative values".into(),
            ));
        }
        if w.iter().sum::<f64>() <= 0.0 {
            return Err(CoreError::InvalidInput("data weights sum to zero".into()));
        }
    }
    Ok(())
}

fn run<T: Real>(
    y: &[f64],
    x: &[f64],
    wx: Option<&[f64]>,
    sigma2: f64,
    omega: f64,
    cutoff: Option<f64>,
    normals: Option<Normals>,
) -> CoreResult<EStep> {
    let m = y.len() / 3;
    let n = x.len() / 3;
    // Effective number of data points (the outlier term of Eq. 1 counts the represented mass).
    let n_eff = wx.map_or(n as f64, |w| w.iter().sum::<f64>());
    // Centre both sets on the template mean (better conditioned single precision).
    let mut c = [0.0f64; 3];
    for p in y.chunks_exact(3) {
        for a in 0..3 {
            c[a] += p[a];
        }
    }
    for v in &mut c {
        *v /= m as f64;
    }
    let yc: Vec<f64> = y
        .chunks_exact(3)
        .flat_map(|p| [p[0] - c[0], p[1] - c[1], p[2] - c[2]])
        .collect();
    let xc: Vec<f64> = x
        .chunks_exact(3)
        .flat_map(|p| [p[0] - c[0], p[1] - c[1], p[2] - c[2]])
        .collect();

    let two_pi_s2 = 2.0 * std::f64::consts::PI * sigma2;
    // With normals each component's density has the von Mises-Fisher factor
    // `kappa / (2 pi (1 - e^{-2 kappa})) exp(kappa (n . n~ - 1))` and the outlier term the
    // uniform `1 / (4 pi)` on the sphere: `c0` takes their ratio.
    let vmf_norm = normals.map_or(1.0, |nr| {
        nr.kappa / (2.0 * std::f64::consts::PI * (1.0 - (-2.0 * nr.kappa).exp()))
    });
    let outlier_sphere = if normals.is_some() {
        1.0 / (4.0 * std::f64::consts::PI)
    } else {
        1.0
    };
    let c0 = two_pi_s2.powf(1.5) * omega * m as f64 / ((1.0 - omega) * n_eff) * outlier_sphere
        / vmf_norm;
    let inv2s = T::from_f64(1.0 / (2.0 * sigma2));
    // `kappa (1 - n . n~) = |s n - s n~|^2 / (2 sigma^2)` with `s^2 = kappa sigma^2`.
    let s_n = normals.map_or(0.0, |nr| (nr.kappa * sigma2).sqrt());

    // With a cutoff so wide that a 3x3x3 cell block holds most of the template, the exact
    // dense kernel is as fast: it runs instead (bound 0).
    let grid = match cutoff {
        Some(cf) => {
            let radius = cf * sigma2.sqrt();
            Some((Grid::new(&yc, radius)?, radius, (-0.5 * cf * cf).exp()))
        }
        None => None,
    }
    .filter(|(g, _, _)| g.mean_block() < DENSE_BLOCK_FRACTION * m as f64);
    let order: Vec<usize> = match &grid {
        Some((g, _, _)) => g.order().iter().map(|&k| k as usize).collect(),
        None => (0..m).collect(),
    };
    let yn: &[f64] = normals.map_or(&[], |nr| nr.y);
    let has_n = normals.is_some();
    // coordinate `a` of the scaled template normals in accumulator order (empty without)
    let ncol = |a: usize| -> Vec<T> {
        if has_n {
            order
                .iter()
                .map(|&k| T::from_f64(s_n * yn[3 * k + a]))
                .collect()
        } else {
            Vec::new()
        }
    };
    let tpl = Template {
        yx: order.iter().map(|&k| T::from_f64(yc[3 * k])).collect(),
        yy: order.iter().map(|&k| T::from_f64(yc[3 * k + 1])).collect(),
        yz: order.iter().map(|&k| T::from_f64(yc[3 * k + 2])).collect(),
        nx: ncol(0),
        ny: ncol(1),
        nz: ncol(2),
    };
    let xn: Vec<f64> = normals.map_or(Vec::new(), |nr| nr.x.iter().map(|v| s_n * v).collect());

    let (parts, perm) = if has_n {
        chunks::<T, true>(&tpl, grid.as_ref(), &xc, &xn, wx, inv2s, c0)
    } else {
        chunks::<T, false>(&tpl, grid.as_ref(), &xc, &[], wx, inv2s, c0)
    };
    let mut p1s = vec![0.0f64; m];
    let mut pxs = vec![0.0f64; 3 * m];
    let mut pt1s = Vec::with_capacity(n);
    let mut stats = EStepStats::default();
    let mut log_den = 0.0;
    for part in &parts {
        for k in 0..m {
            p1s[k] += part.p1[k].to_f64();
            pxs[3 * k] += part.px[k].to_f64();
            pxs[3 * k + 1] += part.py[k].to_f64();
            pxs[3 * k + 2] += part.pz[k].to_f64();
        }
        pt1s.extend_from_slice(&part.pt1);
        stats.sum_sq += part.sum_sq;
        log_den += part.log_den;
        stats.trunc_bound += part.bound;
        stats.n_pairs += part.n_pairs;
    }
    // Back to input order and input coordinates (PX = P (Xc + c) = P Xc + P1 c).
    let pt1 = if perm.is_empty() {
        pt1s
    } else {
        let mut v = vec![0.0f64; n];
        for (s, &i) in perm.iter().enumerate() {
            v[i] = pt1s[s];
        }
        v
    };
    let mut p1 = vec![0.0f64; m];
    let mut px = vec![0.0f64; 3 * m];
    for (s, &k) in order.iter().enumerate() {
        p1[k] = p1s[s];
        for a in 0..3 {
            px[3 * k + a] = pxs[3 * s + a] + p1s[s] * c[a];
        }
    }
    stats.n_p = pt1.iter().sum();
    stats.sum_x2 = pt1
        .iter()
        .zip(x.chunks_exact(3))
        .map(|(w, p)| w * (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]))
        .sum();
    let log_norm = ((1.0 - omega) * vmf_norm / (m as f64 * two_pi_s2.powf(1.5))).ln();
    stats.nll = -log_den - n_eff * log_norm;
    stats.e_gmm = stats.sum_sq / (2.0 * sigma2) + 1.5 * stats.n_p * sigma2.ln();
    Ok(EStep { p1, pt1, px, stats })
}

/// E-step sufficient statistics (Eq. 4) of template `y` (flat `(M, 3)`) against data `x`
/// (flat `(N, 3)`), metres.
///
/// `cutoff = Some(c)` keeps only pairs with `|x_i - y_m| < c * sigma` (see module docs for
/// the error bound); `None` is the exact dense E-step.
pub fn estep(
    y: &[f64],
    x: &[f64],
    sigma2: f64,
    omega: f64,
    cutoff: Option<f64>,
    precision: Precision,
) -> CoreResult<EStep> {
    estep_weighted(y, x, None, sigma2, omega, cutoff, precision)
}

/// [`estep`] with a non-negative weight (multiplicity) per data point: point `i` counts as
/// `w_i` coincident points (e.g. a voxel centroid standing for `w_i` observations), so
/// `Pt1_i`, `P1`, `PX`, `N_p`, the Eq. 12 sum and the log-likelihood are weighted and the
/// outlier constant `c0` uses `N = sum_i w_i`. `None` = all ones (bitwise equal to [`estep`]).
pub fn estep_weighted(
    y: &[f64],
    x: &[f64],
    wx: Option<&[f64]>,
    sigma2: f64,
    omega: f64,
    cutoff: Option<f64>,
    precision: Precision,
) -> CoreResult<EStep> {
    validate(y, x, sigma2, omega, cutoff)?;
    validate_weights(x, wx)?;
    match precision {
        Precision::Double => run::<f64>(y, x, wx, sigma2, omega, cutoff, None),
        Precision::Single => run::<f32>(y, x, wx, sigma2, omega, cutoff, None),
    }
}

/// [`estep_weighted`] with surface normals: each pair's Gaussian is multiplied by the von
/// Mises-Fisher factor `exp(kappa (n_i . n~_m - 1))` (normalised, and the outlier term
/// uniform over directions), so that a template point prefers data whose surface faces the
/// same way. `P1`, `PX`, `Pt1`, the Eq. 12 sum (positions only) keep their meaning; the
/// log-likelihood includes the normal factor. `kappa = 0` is [`estep_weighted`] exactly.
#[allow(clippy::too_many_arguments)]
pub fn estep_normals(
    y: &[f64],
    x: &[f64],
    wx: Option<&[f64]>,
    normals: Normals,
    sigma2: f64,
    omega: f64,
    cutoff: Option<f64>,
    precision: Precision,
) -> CoreResult<EStep> {
    let Normals {
        y: yn,
        x: xn,
        kappa,
    } = normals;
    if yn.len() != y.len() || xn.len() != x.len() {
        return Err(CoreError::InvalidInput(format!(
            "normals must match the points: template {} vs {}, data {} vs {} values",
            yn.len(),
            y.len(),
            xn.len(),
            x.len()
        )));
    }
    if !(kappa.is_finite() && kappa >= 0.0) {
        return Err(CoreError::InvalidInput(format!(
            "kappa must be non-negative and finite, got {kappa}"
        )));
    }
    if !yn.iter().chain(xn).all(|v| v.is_finite()) {
        return Err(CoreError::NonFinite("normals".into()));
    }
    if kappa == 0.0 {
        return estep_weighted(y, x, wx, sigma2, omega, cutoff, precision);
    }
    validate(y, x, sigma2, omega, cutoff)?;
    validate_weights(x, wx)?;
    match precision {
        Precision::Double => run::<f64>(y, x, wx, sigma2, omega, cutoff, Some(normals)),
        Precision::Single => run::<f32>(y, x, wx, sigma2, omega, cutoff, Some(normals)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(n: usize, seed: f64) -> Vec<f64> {
        (0..3 * n)
            .map(|i| ((i as f64 + seed) * 0.754_877_666).fract() * 0.3)
            .collect()
    }

    fn brute(y: &[f64], x: &[f64], s2: f64, w: f64) -> (Vec<f64>, Vec<f64>, f64) {
        let (m, n) = (y.len() / 3, x.len() / 3);
        let c0 =
            (2.0 * std::f64::consts::PI * s2).powf(1.5) * w * m as f64 / ((1.0 - w) * n as f64);
        let mut p1 = vec![0.0; m];
        let mut pt1 = vec![0.0; n];
        let mut ss = 0.0;
        for i in 0..n {
            let e: Vec<f64> = (0..m)
                .map(|k| {
                    let d2: f64 = (0..3).map(|a| (x[3 * i + a] - y[3 * k + a]).powi(2)).sum();
                    (-d2 / (2.0 * s2)).exp()
                })
                .collect();
            let den: f64 = e.iter().sum::<f64>() + c0;
            for k in 0..m {
                let d2: f64 = (0..3).map(|a| (x[3 * i + a] - y[3 * k + a]).powi(2)).sum();
                p1[k] += e[k] / den;
                pt1[i] += e[k] / den;
                ss += e[k] / den * d2;
            }
        }
        (p1, pt1, ss)
    }

    #[test]
    fn exp_matches_std() {
        for i in 0..2000 {
            let x = -(i as f64) * 0.37;
            let e = <f64 as Real>::exp_neg(x);
            let r = x.exp();
            if x < EXP_FLOOR_F64 {
                assert_eq!(e, 0.0);
            } else {
                assert!((e - r).abs() <= 4e-16 * r, "{x} {e} {r}");
            }
            let xf = x as f32;
            let ef = <f32 as Real>::exp_neg(xf) as f64;
            let rf = (xf as f64).exp();
            if xf < EXP_FLOOR_F32 {
                assert_eq!(ef, 0.0);
            } else {
                assert!((ef - rf).abs() <= 5e-7 * rf, "{xf} {ef} {rf}");
            }
        }
    }

    #[test]
    fn dense_matches_brute_force_and_is_thread_independent() {
        let y = cloud(300, 0.1);
        let x = cloud(700, 7.3);
        let (p1, pt1, ss) = brute(&y, &x, 0.003, 0.1);
        let r = estep(&y, &x, 0.003, 0.1, None, Precision::Double).unwrap();
        for k in 0..p1.len() {
            assert!((r.p1[k] - p1[k]).abs() < 1e-12);
        }
        for i in 0..pt1.len() {
            assert!((r.pt1[i] - pt1[i]).abs() < 1e-12);
        }
        assert!((r.stats.sum_sq - ss).abs() < 1e-12 * ss.max(1.0));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let r1 = pool.install(|| estep(&y, &x, 0.003, 0.1, Some(3.0), Precision::Single).unwrap());
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let r3 = pool.install(|| estep(&y, &x, 0.003, 0.1, Some(3.0), Precision::Single).unwrap());
        assert_eq!(r1.p1, r3.p1);
        assert_eq!(r1.px, r3.px);
        assert_eq!(r1.stats, r3.stats);
    }

    #[test]
    fn truncated_grouped_kernel_matches_cut_brute_force_and_is_thread_independent() {
        // Enough template points over enough cells that the grid (not the dense fallback)
        // runs; data partly outside the template's box (empty blocks) and in input order
        // unrelated to the grid (Pt1 must come back in input order).
        let rnd = |n: usize, seed: u64| -> Vec<f64> {
            let mut s = seed;
            (0..3 * n)
                .map(|_| {
                    s = s
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1_442_695_040_888_963_407);
                    (s >> 11) as f64 / (1u64 << 53) as f64 * 0.3
                })
                .collect()
        };
        let y = rnd(3000, 1);
        let mut x = rnd(1500, 2);
        for v in x.iter_mut().step_by(7) {
            *v += 0.5;
        }
        let (s2, om, c) = (1e-4, 0.05, 3.0);
        let (m, n) = (y.len() / 3, x.len() / 3);
        let w: Vec<f64> = (0..n).map(|i| 0.5 + (i % 4) as f64).collect();
        let r = estep_weighted(&y, &x, Some(&w), s2, om, Some(c), Precision::Double).unwrap();
        assert!(r.stats.n_pairs < (m * n) as u64 / 4, "grid path expected");
        let n_eff: f64 = w.iter().sum();
        let c0 = (2.0 * std::f64::consts::PI * s2).powf(1.5) * om * m as f64 / ((1.0 - om) * n_eff);
        let r2 = c * c * s2;
        let mut p1 = vec![0.0; m];
        let mut px = vec![0.0; 3 * m];
        let mut pt1 = vec![0.0; n];
        for i in 0..n {
            let d2: Vec<f64> = (0..m)
                .map(|k| (0..3).map(|a| (x[3 * i + a] - y[3 * k + a]).powi(2)).sum())
                .collect();
            let e: Vec<f64> = d2
                .iter()
                .map(|&d| if d < r2 { (-d / (2.0 * s2)).exp() } else { 0.0 })
                .collect();
            let den: f64 = e.iter().sum::<f64>() + c0;
            for k in 0..m {
                let p = w[i] * e[k] / den;
                p1[k] += p;
                pt1[i] += p;
                for a in 0..3 {
                    px[3 * k + a] += p * x[3 * i + a];
                }
            }
        }
        for k in 0..m {
            assert!((r.p1[k] - p1[k]).abs() < 1e-10, "p1[{k}]");
            for a in 0..3 {
                assert!((r.px[3 * k + a] - px[3 * k + a]).abs() < 1e-10);
            }
        }
        for i in 0..n {
            assert!((r.pt1[i] - pt1[i]).abs() < 1e-10, "pt1[{i}]");
        }
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                estep_weighted(&y, &x, Some(&w), s2, om, Some(c), Precision::Single).unwrap()
            })
        };
        let (a, b) = (run(1), run(3));
        assert_eq!(a.p1, b.p1);
        assert_eq!(a.pt1, b.pt1);
        assert_eq!(a.px, b.px);
        assert_eq!(a.stats, b.stats);
    }

    #[test]
    fn integer_weights_equal_duplicated_points() {
        let y = cloud(200, 0.4);
        let x = cloud(500, 3.1);
        let w: Vec<f64> = (0..500).map(|i| (i % 3 + 1) as f64).collect();
        let dup: Vec<f64> = x
            .chunks_exact(3)
            .zip(&w)
            .flat_map(|(p, &k)| std::iter::repeat_n([p[0], p[1], p[2]], k as usize).flatten())
            .collect();
        for cutoff in [None, Some(4.0)] {
            let a =
                estep_weighted(&y, &x, Some(&w), 0.004, 0.1, cutoff, Precision::Double).unwrap();
            let b = estep(&y, &dup, 0.004, 0.1, cutoff, Precision::Double).unwrap();
            for k in 0..200 {
                assert!((a.p1[k] - b.p1[k]).abs() < 1e-10);
                for c in 0..3 {
                    assert!((a.px[3 * k + c] - b.px[3 * k + c]).abs() < 1e-10);
                }
            }
            let rel = |u: f64, v: f64| (u - v).abs() <= 1e-10 * v.abs().max(1.0);
            assert!(rel(a.stats.n_p, b.stats.n_p));
            assert!(rel(a.stats.sum_sq, b.stats.sum_sq));
            assert!(rel(a.stats.sum_x2, b.stats.sum_x2));
            assert!(rel(a.stats.nll, b.stats.nll));
        }
        assert!(
            estep_weighted(&y, &x, Some(&w[..10]), 0.004, 0.1, None, Precision::Double).is_err()
        );
    }

    /// Unit vectors from a deterministic sequence.
    fn unit(n: usize, seed: f64) -> Vec<f64> {
        let raw = cloud(n, seed);
        raw.chunks_exact(3)
            .flat_map(|p| {
                let v = [p[0] - 0.15, p[1] - 0.15, p[2] - 0.15 + 1e-3];
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                [v[0] / l, v[1] / l, v[2] / l]
            })
            .collect()
    }

    #[test]
    fn normals_match_a_brute_force_mixture_with_a_von_mises_fisher_factor() {
        let (m, n) = (250, 600);
        let y = cloud(m, 0.3);
        let x = cloud(n, 5.1);
        let yn = unit(m, 2.2);
        let xn = unit(n, 9.7);
        let (s2, om, kappa): (f64, f64, f64) = (0.003, 0.1, 3.0);
        // Oracle: Gaussian x normalised vMF per component, uniform position x uniform
        // direction (1 / (4 pi)) for the outlier term; everything straight from the formulas.
        let pi = std::f64::consts::PI;
        let vmf = kappa / (2.0 * pi * (1.0 - (-2.0 * kappa).exp()));
        let gauss = 1.0 / (2.0 * pi * s2).powf(1.5);
        let out = om / (n as f64) / (4.0 * pi);
        let (mut p1, mut pt1, mut ss, mut nll) = (vec![0.0; m], vec![0.0; n], 0.0, 0.0);
        let mut px = vec![0.0; 3 * m];
        for i in 0..n {
            let mut dens = vec![0.0; m];
            for k in 0..m {
                let d2: f64 = (0..3).map(|a| (x[3 * i + a] - y[3 * k + a]).powi(2)).sum();
                let c: f64 = (0..3).map(|a| xn[3 * i + a] * yn[3 * k + a]).sum();
                dens[k] = (1.0 - om) / m as f64
                    * gauss
                    * (-d2 / (2.0 * s2)).exp()
                    * vmf
                    * (kappa * (c - 1.0)).exp();
            }
            let den: f64 = dens.iter().sum::<f64>() + out;
            nll -= den.ln();
            for k in 0..m {
                let d2: f64 = (0..3).map(|a| (x[3 * i + a] - y[3 * k + a]).powi(2)).sum();
                let p = dens[k] / den;
                p1[k] += p;
                pt1[i] += p;
                ss += p * d2;
                for a in 0..3 {
                    px[3 * k + a] += p * x[3 * i + a];
                }
            }
        }
        let nr = Normals {
            y: &yn,
            x: &xn,
            kappa,
        };
        for (cut, prec, tol) in [
            (None, Precision::Double, 1e-10),
            (Some(8.0), Precision::Double, 1e-9),
            (None, Precision::Single, 2e-5),
            (Some(8.0), Precision::Single, 2e-5),
        ] {
            let r = estep_normals(&y, &x, None, nr, s2, om, cut, prec).unwrap();
            for k in 0..m {
                assert!(
                    (r.p1[k] - p1[k]).abs() < tol * p1[k].max(1.0),
                    "{k} {cut:?}"
                );
                for a in 0..3 {
                    assert!((r.px[3 * k + a] - px[3 * k + a]).abs() < tol * p1[k].max(1.0));
                }
            }
            for i in 0..n {
                assert!((r.pt1[i] - pt1[i]).abs() < tol, "{i} {cut:?}");
            }
            assert!((r.stats.sum_sq - ss).abs() < tol * ss.max(1.0));
            assert!(
                (r.stats.nll - nll).abs() < tol * nll.abs().max(1.0),
                "{cut:?}"
            );
        }
        // kappa = 0 is the plain E-step; the factor changes the posteriors when on.
        let z = Normals { kappa: 0.0, ..nr };
        let plain = estep(&y, &x, s2, om, None, Precision::Double).unwrap();
        let r0 = estep_normals(&y, &x, None, z, s2, om, None, Precision::Double).unwrap();
        assert_eq!(plain.p1, r0.p1);
        let r1 = estep_normals(&y, &x, None, nr, s2, om, None, Precision::Double).unwrap();
        assert!(plain
            .p1
            .iter()
            .zip(&r1.p1)
            .any(|(a, b)| (a - b).abs() > 1e-3));
        // Mismatched lengths are refused, not a panic.
        let bad = Normals { y: &yn[..30], ..nr };
        assert!(estep_normals(&y, &x, None, bad, s2, om, None, Precision::Double).is_err());
    }
}
