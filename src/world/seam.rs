//! Joining a generated tile to the neighbours it was made from.
//!
//! The TCM sees its input neighbours, but its output does not continue their edges exactly: a
//! step along the shared edge is what the world's seam figure measures, a change of slope (a
//! fold) what its crease figure measures. [`join_edges`] removes both where they arise, on
//! each side whose neighbour was an input, in two stages:
//!
//! 1. Heights: the tile's edge sample is moved to where the neighbour's surface continues (its
//!    edge plus its last slope across the edge) and the correction spreads into the tile as
//!    the smoothest field (a membrane: Laplace's equation, fixed on those edges, free — zero
//!    normal slope — on the others). This alone left a fold along each joined edge (crease
//!    figure 1.76, procedural 1.02).
//! 2. Slopes: the tile's first step inside is bent towards the neighbour's slope across the
//!    edge by a field that is zero on the edge and fades along cubic Hermite curves over half
//!    a tile; the x and z sides' fields are combined as a Coons patch (Boolean sum). The slope
//!    mismatch is smoothed along the edge first ([`UNFOLD_SMOOTH_PX`]): bent sample by sample,
//!    its noise became streaks across the edge.
//!
//! The result is a pure function of the tile and its inputs, so the world stays a pure
//! function of (seed, weights, tile) whatever the visit order.

/// Over-relaxation sweeps of the membrane (a 32² tile converges to < 0.1 % in ~100).
pub const SWEEPS: usize = 160;
/// Over-relaxation factor of the sweeps.
const OMEGA: f32 = 1.85;
/// Standard deviation (samples along the edge) of the Gaussian that smooths the slope
/// mismatch before stage 2 bends it away.
pub const UNFOLD_SMOOTH_PX: f32 = 3.0;
/// Stage 2 fades out (a cubic over this many samples along the edge) towards a corner where
/// the perpendicular side is joined too: there the two sides' heights are both fixed, so
/// neither may bend the other's edge.
pub const CORNER_FADE_PX: usize = 6;

/// The sides of a tile, in the order [`join_edges`] takes its neighbours: −x, +x, −z, +z.
pub const SIDES: [(i32, i32); 4] = [(-1, 0), (1, 0), (0, -1), (0, 1)];

/// Value and slope weights of the cubic Hermite curve at `d` samples from the edge over a
/// span of `span` samples: (1 − 3t² + 2t³, t − 2t² + t³) for t = d / span, zero beyond.
fn hermite(d: f32, span: f32) -> (f32, f32) {
    let t = d / span;
    if t >= 1.0 {
        return (0.0, 0.0);
    }
    (1.0 - t * t * (3.0 - 2.0 * t), t * (1.0 - t) * (1.0 - t))
}

/// Sample index (u, v) at `d` samples into the tile from side `side`, `k` along its edge.
fn at_side(side: usize, n: usize, d: usize, k: usize) -> (usize, usize) {
    match side {
        0 => (d, k),
        1 => (n - 1 - d, k),
        2 => (k, d),
        _ => (k, n - 1 - d),
    }
}

/// The field (`n`², row-major) that, on each side of `sides` with data, takes the value
/// `value[k]` at the edge sample and `value[k] + step[k]` at the one inside it, and fades
/// along a cubic Hermite curve to nothing (value and slope) half a tile in.
fn extend(n: usize, sides: &[(usize, Vec<f32>, Vec<f32>)]) -> Vec<f32> {
    let span = (n / 2) as f32;
    let (h0, h1) = hermite(1.0, span);
    let mut out = vec![0f32; n * n];
    for (side, value, step) in sides {
        for k in 0..n {
            let (a, b) = (value[k], step[k]);
            // The slope coefficient that puts the first sample inside at a + b exactly.
            let slope = (a + b - a * h0) / (span * h1);
            for d in 0..n / 2 {
                let (w0, w1) = hermite(d as f32, span);
                let (u, v) = at_side(*side, n, d, k);
                out[v * n + u] += a * w0 + slope * span * w1;
            }
        }
    }
    out
}

/// Moves the edges of `tile` (`n`×`n` heights, row-major, rows along +z) onto the surfaces of
/// its input neighbours (`n`×`n` each, in [`SIDES`] order; `None` where a side was not an
/// input), bends its slope across them towards theirs, and spreads both corrections smoothly
/// inside. Without neighbours nothing changes.
pub fn join_edges(tile: &mut [f32], n: usize, neighbours: [Option<&[f32]>; 4]) {
    // The neighbours do not change, so their continuations serve both stages.
    let Some(sides) = joined_sides(tile, n, &neighbours) else { return };
    join_heights(tile, n, &sides);
    join_slopes(tile, n, &sides, &neighbours);
}

/// The continuations of `tile`'s (`n`×`n`) input `neighbours`, or `None` without any; checks
/// the sizes.
fn joined_sides(tile: &[f32], n: usize, neighbours: &[Option<&[f32]>; 4]) -> Option<Vec<Continuation>> {
    assert_eq!(tile.len(), n * n);
    assert!(n >= 4, "a tile of {n}² samples has no interior");
    if neighbours.iter().all(Option::is_none) {
        return None;
    }
    for nb in neighbours.iter().flatten() {
        assert_eq!(nb.len(), n * n);
    }
    Some(continuations(n, neighbours).collect())
}

/// Moves the edges of `tile` (`n`×`n`) onto the surfaces of its input `neighbours` as
/// [`join_edges`]'s first stage does, while its other edges keep their heights: the correction
/// is a membrane fixed on every edge (zero on those not joined), converged for tiles of up to
/// 128² samples. For a tile whose other neighbours were made without the join (a grown 32 m
/// tile beside a pinned one): [`join_edges`] moves the free edges too, and so opens steps
/// towards those neighbours. No slope stage: bending the tile's first step towards a real
/// DEM's sample-to-sample slopes drew streaks across the edge.
pub fn join_edges_holding_others(tile: &mut [f32], n: usize, neighbours: [Option<&[f32]>; 4]) {
    let Some(sides) = joined_sides(tile, n, &neighbours) else { return };
    // Successive over-relaxation at its optimal factor for this grid.
    let omega = 2.0 / (1.0 + libm::sinf(std::f32::consts::PI / n as f32));
    join_heights_with(tile, n, &sides, true, 3 * n, omega);
}

/// One joined side (index into [`SIDES`]) and, along its edge (k = 0..n), where the
/// neighbour's surface continues onto the tile's edge sample and the neighbour's last slope
/// across the edge (metres per sample).
type Continuation = (usize, Vec<f32>, Vec<f32>);

/// Per joined side, along its edge (k = 0..n): the neighbour's facing sample plus its last
/// slope across the edge (where its surface continues), and that slope (metres per sample).
fn continuations<'a>(n: usize, neighbours: &'a [Option<&[f32]>; 4]) -> impl Iterator<Item = Continuation> + 'a {
    neighbours.iter().enumerate().filter_map(move |(side, nb)| {
        let nb = (*nb)?;
        // The neighbour's own side that faces this one.
        let facing = side ^ 1;
        let (mut target, mut slope) = (vec![0f32; n], vec![0f32; n]);
        for k in 0..n {
            let (fu, fv) = at_side(facing, n, 0, k);
            let (bu, bv) = at_side(facing, n, 1, k);
            slope[k] = nb[fv * n + fu] - nb[bv * n + bu];
            target[k] = nb[fv * n + fu] + slope[k];
        }
        Some((side, target, slope))
    })
}

/// Stage 1: the joined edges' samples onto the neighbours' continuations, the correction
/// spread as a membrane.
fn join_heights(tile: &mut [f32], n: usize, sides: &[Continuation]) {
    join_heights_with(tile, n, sides, false, SWEEPS, OMEGA);
}

/// [`join_heights`] with `sweeps` sweeps at over-relaxation `omega`; `hold_others`: the
/// edges not joined keep their heights (the correction is fixed at 0 there) instead of being
/// free.
fn join_heights_with(tile: &mut [f32], n: usize, sides: &[Continuation], hold_others: bool, sweeps: usize, omega: f32) {
    // The correction each side asks for at each edge sample (corners: the mean of two).
    let mut fixed: Vec<Option<(f32, u32)>> = vec![None; n * n];
    for (side, target, _) in sides {
        for k in 0..n {
            let (u, v) = at_side(*side, n, 0, k);
            let (sum, count) = fixed[v * n + u].unwrap_or((0.0, 0));
            fixed[v * n + u] = Some((sum + target[k] - tile[v * n + u], count + 1));
        }
    }
    if hold_others {
        for side in (0..4).filter(|s| !sides.iter().any(|(j, _, _)| j == s)) {
            for k in 0..n {
                let (u, v) = at_side(side, n, 0, k);
                fixed[v * n + u].get_or_insert((0.0, 1));
            }
        }
    }
    let fixed: Vec<Option<f32>> = fixed.into_iter().map(|s| s.map(|(sum, k)| sum / k as f32)).collect();
    let mut c: Vec<f32> = fixed.iter().map(|f| f.unwrap_or(0.0)).collect();
    for _ in 0..sweeps {
        for v in 0..n {
            for u in 0..n {
                if fixed[v * n + u].is_some() {
                    continue;
                }
                // Free sides mirror the sample inside them (zero normal slope).
                let l = c[v * n + if u > 0 { u - 1 } else { 1 }];
                let r = c[v * n + if u + 1 < n { u + 1 } else { n - 2 }];
                let t = c[if v > 0 { v - 1 } else { 1 } * n + u];
                let b = c[if v + 1 < n { v + 1 } else { n - 2 } * n + u];
                let p = &mut c[v * n + u];
                *p += omega * (0.25 * (l + r + t + b) - *p);
            }
        }
    }
    for (h, d) in tile.iter_mut().zip(&c) {
        *h += d;
    }
}

/// `values` smoothed by a Gaussian of [`UNFOLD_SMOOTH_PX`] samples (weights renormalised
/// where the kernel leaves the edge).
fn smooth_along_edge(values: &[f32]) -> Vec<f32> {
    let reach = (3.0 * UNFOLD_SMOOTH_PX).ceil() as i64;
    let w: Vec<f32> = (-reach..=reach).map(|d| libm::expf(-0.5 * (d as f32 / UNFOLD_SMOOTH_PX).powi(2))).collect();
    (0..values.len() as i64)
        .map(|k| {
            let (mut sum, mut weight) = (0.0, 0.0);
            for d in -reach..=reach {
                if let Some(v) = usize::try_from(k + d).ok().and_then(|j| values.get(j)) {
                    sum += w[(d + reach) as usize] * v;
                    weight += w[(d + reach) as usize];
                }
            }
            sum / weight
        })
        .collect()
}

/// Stage 2: the tile's first step inside each joined edge bent towards the neighbour's slope
/// (the mismatch smoothed along the edge), by a field that is zero on the edges.
fn join_slopes(tile: &mut [f32], n: usize, sides: &[Continuation], neighbours: &[Option<&[f32]>; 4]) {
    let (mut x_sides, mut z_sides) = (Vec::new(), Vec::new());
    for &(side, _, ref slope) in sides {
        let mismatch: Vec<f32> = (0..n)
            .map(|k| {
                let (ou, ov) = at_side(side, n, 0, k);
                let (iu, iv) = at_side(side, n, 1, k);
                slope[k] - (tile[iv * n + iu] - tile[ov * n + ou])
            })
            .collect();
        let mut step = smooth_along_edge(&mismatch);
        // The perpendicular sides at this edge's k = 0 and k = n − 1 ends.
        let (low, high) = if side < 2 { (2, 3) } else { (0, 1) };
        for k in 0..CORNER_FADE_PX.min(n) {
            let keep = 1.0 - hermite(k as f32, CORNER_FADE_PX as f32).0;
            if neighbours[low].is_some() {
                step[k] *= keep;
            }
            if neighbours[high].is_some() {
                step[n - 1 - k] *= keep;
            }
        }
        if side < 2 { &mut x_sides } else { &mut z_sides }.push((side, vec![0f32; n], step));
    }
    // Coons patch: P_x + P_z − P_x P_z, where P_x P_z carries P_z's own values and steps on
    // the x sides, so each joined edge keeps its value (zero) and gets its own step.
    let pz = extend(n, &z_sides);
    let px = extend(n, &x_sides);
    let pz_on_x: Vec<(usize, Vec<f32>, Vec<f32>)> = x_sides
        .iter()
        .map(|(side, _, _)| {
            let value: Vec<f32> = (0..n)
                .map(|k| {
                    let (u, v) = at_side(*side, n, 0, k);
                    pz[v * n + u]
                })
                .collect();
            let step: Vec<f32> = (0..n)
                .map(|k| {
                    let (u, v) = at_side(*side, n, 1, k);
                    pz[v * n + u] - value[k]
                })
                .collect();
            (*side, value, step)
        })
        .collect();
    let pxpz = extend(n, &pz_on_x);
    for (p, h) in tile.iter_mut().enumerate() {
        *h += px[p] + pz[p] - pxpz[p];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(n: usize, a: f32, b: f32, c0: f32) -> Vec<f32> {
        (0..n * n).map(|p| c0 + a * (p % n) as f32 + b * (p / n) as f32).collect()
    }

    /// Held on its other edges, a bumpy 128² tile 40 m too high beside a sloping left
    /// neighbour lands on the neighbour's continuation along the joined edge (to 1 mm), keeps
    /// every other edge sample bit for bit (the corners belong to the joined edge), and the
    /// correction inside is smooth: no step between neighbouring samples over 2 m (the edge's
    /// 40 m spread over the tile) except within 16 samples of the joined edge's two ends, where
    /// the correction turns from 40 m to the held edges' 0 m (steps of ~21 m next to the corner,
    /// ~3 m 8 samples from it).
    #[test]
    fn a_tile_joined_holding_its_other_edges_keeps_them_and_meets_the_neighbour() {
        let n = 128;
        let left = plane(n, 2.0, 0.5, 100.0);
        let bump = |p: usize| ((p % n) as f32 * 0.3).sin() * 3.0 + ((p / n) as f32 * 0.2).cos() * 2.0;
        let mut tile: Vec<f32> = (0..n * n).map(|p| 100.0 + 2.0 * (n + p % n) as f32 + 0.5 * (p / n) as f32 + 40.0 + bump(p)).collect();
        let before = tile.clone();
        join_edges_holding_others(&mut tile, n, [Some(&left), None, None, None]);
        for v in 0..n {
            let step = tile[v * n] - left[v * n + n - 1];
            assert!((step - 2.0).abs() < 1e-3, "row {v}: step {step} m across the edge, slope 2 m");
        }
        let held = (1..n).map(|u| (u, 0)).chain((1..n).map(|u| (u, n - 1))).chain((0..n).map(|v| (n - 1, v)));
        for (u, v) in held {
            assert_eq!(tile[v * n + u].to_bits(), before[v * n + u].to_bits(), "({u}, {v}) moved");
        }
        let d: Vec<f32> = tile.iter().zip(&before).map(|(a, b)| a - b).collect();
        let near_end = |u: usize, v: usize| u < 16 && (v < 16 || v >= n - 16);
        let worst = (1..n - 1)
            .flat_map(|v| (1..n - 1).map(move |u| (u, v)))
            .filter(|&(u, v)| !near_end(u, v))
            .map(|(u, v)| (d[v * n + u] - d[v * n + u - 1]).abs().max((d[v * n + u] - d[(v - 1) * n + u]).abs()))
            .fold(0f32, f32::max);
        assert!(worst < 2.0, "the correction steps by up to {worst} m");
    }

    /// A tile 40 m too high beside a sloping left neighbour: after joining, the step across
    /// the shared edge equals the slope on both sides (to 1 mm); the far, free side moves
    /// less than the joined one, and a tile without neighbours is untouched.
    #[test]
    fn a_tile_continues_its_input_neighbour_across_the_edge() {
        let n = 32;
        let left = plane(n, 2.0, 0.5, 100.0);
        // Where the neighbour's surface continues (column n, n+1, …), but 40 m higher.
        let mut tile: Vec<f32> = (0..n * n).map(|p| 100.0 + 2.0 * (n + p % n) as f32 + 0.5 * (p / n) as f32 + 40.0).collect();
        let before = tile.clone();
        join_edges(&mut tile, n, [Some(&left), None, None, None]);
        for v in 0..n {
            let step = tile[v * n] - left[v * n + n - 1];
            assert!((step - 2.0).abs() < 1e-3, "row {v}: step {step} m across the edge, slope 2 m");
        }
        let moved = |u: usize| (0..n).map(|v| (tile[v * n + u] - before[v * n + u]).abs()).fold(0f32, f32::max);
        assert!((moved(0) - 40.0).abs() < 1e-3 && moved(n - 1) < moved(0), "moved {} at the edge, {} far away", moved(0), moved(n - 1));
        let mut alone = before.clone();
        join_edges(&mut alone, n, [None; 4]);
        assert_eq!(alone, before);
    }

    /// Joined on all four sides to one plane, a bumpy tile's edges land on that plane's
    /// continuation (each edge sample within 1 mm), and the correction is smooth: no step
    /// between neighbouring samples inside exceeds the largest edge correction / 4.
    #[test]
    fn four_sides_join_and_the_correction_is_smooth() {
        let n = 32;
        let bump: Vec<f32> = (0..n * n).map(|p| 30.0 * (((p % n) as f32 * 0.3).sin() + ((p / n) as f32 * 0.2).cos())).collect();
        let world = |x: i32, z: i32| 500.0 + 1.5 * x as f32 - 0.7 * z as f32;
        let nb = |di: i32, dj: i32| -> Vec<f32> { (0..n * n).map(|p| world(di * n as i32 + (p % n) as i32, dj * n as i32 + (p / n) as i32)).collect() };
        let sides: Vec<Vec<f32>> = SIDES.iter().map(|&(di, dj)| nb(di, dj)).collect();
        let mut tile: Vec<f32> = (0..n * n).map(|p| world((p % n) as i32, (p / n) as i32) + bump[p]).collect();
        let before = tile.clone();
        join_edges(&mut tile, n, [Some(&sides[0]), Some(&sides[1]), Some(&sides[2]), Some(&sides[3])]);
        let mut worst_edge = 0f32;
        for k in 0..n {
            for (u, v) in [(0, k), (n - 1, k), (k, 0), (k, n - 1)] {
                worst_edge = worst_edge.max((tile[v * n + u] - world(u as i32, v as i32)).abs());
            }
        }
        assert!(worst_edge < 1e-3, "edge sample off the plane by {worst_edge} m");
        let corr: Vec<f32> = tile.iter().zip(&before).map(|(a, b)| a - b).collect();
        let biggest = corr.iter().fold(0f32, |m, c| m.max(c.abs()));
        for v in 1..n - 1 {
            for u in 1..n - 2 {
                let d = (corr[v * n + u + 1] - corr[v * n + u]).abs();
                assert!(d <= biggest / 4.0, "correction jumps {d} m at ({u},{v}), largest {biggest} m");
            }
        }
    }

    /// A tile tilted against its neighbours (0.6 m per sample along x, −0.4 along z, plus a
    /// gentle wave) joined on its −x and −z sides to a curved surface: away from the ends of
    /// the edges ([`CORNER_FADE_PX`]), each second difference straddling a joined edge is
    /// within 4.5 cm of the surface's own (whose 4 cm the linear continuation leaves out) — no
    /// fold — while the membrane alone leaves folds over 0.3 m.
    #[test]
    fn joined_edges_keep_the_neighbours_slope_no_fold() {
        let n = 32;
        let world = |x: i32, z: i32| 300.0 + 0.02 * (x * x) as f32 - 0.015 * (z * z) as f32 + 0.01 * (x * z) as f32;
        let cut = |di: i32, dj: i32| -> Vec<f32> { (0..n * n).map(|p| world(di * n as i32 + (p % n) as i32, dj * n as i32 + (p / n) as i32)).collect() };
        let (left, top) = (cut(-1, 0), cut(0, -1));
        let tilted: Vec<f32> = cut(0, 0)
            .iter()
            .enumerate()
            .map(|(p, h)| {
                let (x, z) = ((p % n) as f32, (p / n) as f32);
                h + 0.6 * x - 0.4 * z + 3.0 * (0.08 * (x + z)).sin() - 12.0
            })
            .collect();
        let worst_fold = |tile: &[f32]| {
            let mut worst = 0f32;
            for k in CORNER_FADE_PX..n - CORNER_FADE_PX {
                let across_x = [left[k * n + n - 2], left[k * n + n - 1], tile[k * n], tile[k * n + 1]];
                let across_z = [top[(n - 2) * n + k], top[(n - 1) * n + k], tile[k], tile[n + k]];
                for (line, surface) in [(across_x, 2.0 * 0.02), (across_z, -2.0 * 0.015)] {
                    for w in line.windows(3) {
                        let e = (w[0] - 2.0 * w[1] + w[2] - surface).abs();
                        worst = worst.max(e);
                    }
                }
            }
            worst
        };
        let mut membrane = tilted.clone();
        let neighbours = [Some(left.as_slice()), None, Some(top.as_slice()), None];
        join_heights(&mut membrane, n, &continuations(n, &neighbours).collect::<Vec<_>>());
        let mut joined = tilted.clone();
        join_edges(&mut joined, n, [Some(&left), None, Some(&top), None]);
        let (before, after) = (worst_fold(&membrane), worst_fold(&joined));
        assert!(before > 0.3, "the membrane alone folds by {before} m");
        assert!(after <= 0.045, "second difference across a joined edge off the surface's by {after} m");
    }
}
