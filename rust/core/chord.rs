//! The shortest chord of a silhouette through a pixel (the output stage's depth pass): for
//! each of a few directions, the points of a strip about the line through the pixel, sorted
//! along it, and the run of them around the pixel with no gap wider than a bound.

use crate::core::error::{CoreError, CoreResult};

/// The shortest chord through `centre` of the silhouette of `uv` (flat `(n, 2)` image
/// coordinates; rows with a non-finite value are ignored). For each unit direction `d` of
/// `directions` (flat `(K, 2)`), the points whose distance to the line `centre + s d` is below
/// `band` are sorted by `s`; the chord is the run of them about `s = 0` with no step wider than
/// `gap`, and a direction where `s = 0` falls in a wider step (or past the run's ends), or with
/// fewer than 3 points in its strip, gives none. Returns `(a, b, k)`, the chord from
/// `centre + a d_k` to `centre + b d_k` of the direction `k` with the least `b - a` (the first
/// such direction on a tie), or `None`.
///
/// Each coordinate along or across a direction is `fma(u, d_0, v d_1)`, as numpy's
/// matrix-vector product computes it, so the result equals the numpy form bit for bit where
/// that product uses one fused multiply-add.
pub fn shortest_chord(
    uv: &[f64],
    centre: [f64; 2],
    directions: &[f64],
    band: f64,
    gap: f64,
) -> CoreResult<Option<(f64, f64, usize)>> {
    if !uv.len().is_multiple_of(2) || !directions.len().is_multiple_of(2) {
        return Err(CoreError::InvalidInput(
            "shortest_chord: uv and directions must have two columns".into(),
        ));
    }
    if !(centre.iter().all(|c| c.is_finite()) && band.is_finite() && gap.is_finite()) {
        return Err(CoreError::NonFinite(format!(
            "shortest_chord: centre {centre:?}, band {band}, gap {gap} must be finite"
        )));
    }
    let rel: Vec<[f64; 2]> = uv
        .chunks_exact(2)
        .filter(|p| p[0].is_finite() && p[1].is_finite())
        .map(|p| [p[0] - centre[0], p[1] - centre[1]])
        .collect();
    let mut best: Option<(f64, f64, usize)> = None;
    let mut s: Vec<f64> = Vec::with_capacity(rel.len());
    for (k, d) in directions.chunks_exact(2).enumerate() {
        s.clear();
        s.extend(rel.iter().filter_map(|r| {
            let across = r[0].mul_add(-d[1], r[1] * d[0]);
            (across.abs() < band).then(|| r[0].mul_add(d[0], r[1] * d[1]))
        }));
        if s.len() < 3 {
            continue;
        }
        s.sort_unstable_by(f64::total_cmp);
        let hi = s.partition_point(|&x| x < 0.0);
        if hi == 0 || hi >= s.len() || s[hi] - s[hi - 1] > gap {
            continue;
        }
        let mut lo = hi - 1;
        while lo > 0 && s[lo] - s[lo - 1] <= gap {
            lo -= 1;
        }
        let mut up = hi;
        while up + 1 < s.len() && s[up + 1] - s[up] <= gap {
            up += 1;
        }
        let (a, b) = (s[lo], s[up]);
        if best.is_none_or(|(ba, bb, _)| b - a < bb - ba) {
            best = Some((a, b, k));
        }
    }
    Ok(best)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chord_of_a_bar_runs_across_it_and_a_hole_has_none() {
        // a bar 2 x 0.4 sampled on a 0.02 grid, with a 0.3 x 0.3 hole about (0.5, 0): through
        // the origin the shortest chord runs across the bar (the vertical direction, from
        // -0.2 to 0.2); in the hole every direction's strip has a step wider than the bound
        let mut uv = Vec::new();
        for i in -50..=50 {
            for j in -10..=10 {
                let (x, y) = (i as f64 * 0.02, j as f64 * 0.02);
                if !((x - 0.5).abs() < 0.15 && y.abs() < 0.15) {
                    uv.extend_from_slice(&[x, y]);
                }
            }
        }
        let dirs: Vec<f64> = (0..12)
            .flat_map(|k| {
                let t = k as f64 * std::f64::consts::PI / 12.0;
                [t.cos(), t.sin()]
            })
            .collect();
        let (a, b, k) = shortest_chord(&uv, [0.0, 0.0], &dirs, 0.009, 0.05)
            .unwrap()
            .unwrap();
        assert_eq!(k, 6, "across the bar");
        assert!((a + 0.2).abs() < 1e-9 && (b - 0.2).abs() < 1e-9, "{a} {b}");
        assert_eq!(
            shortest_chord(&uv, [0.5, 0.0], &dirs, 0.009, 0.05).unwrap(),
            None
        );
        // fewer than three points, bad shapes and non-finite values: none or an error
        assert_eq!(
            shortest_chord(&uv[..4], [0.0, 0.0], &dirs, 0.03, 0.12).unwrap(),
            None
        );
        assert!(shortest_chord(&uv[..3], [0.0, 0.0], &dirs, 0.03, 0.12).is_err());
        assert!(shortest_chord(&uv, [f64::NAN, 0.0], &dirs, 0.03, 0.12).is_err());
    }
}
