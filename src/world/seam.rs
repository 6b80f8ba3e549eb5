//! Joining a generated tile to the neighbours it was made from.
//!
//! The TCM sees its input neighbours, but its output does not continue their edges exactly; a
//! step along the shared edge is the seam the world's seam figure measures. [`join_edges`]
//! removes it where it arises: on each side whose neighbour was an input, the tile's edge row
//! is moved to where the neighbour's surface continues (its edge plus the mean slope across
//! the edge), and the correction spreads into the tile as the smoothest field (a membrane:
//! Laplace's equation, fixed on those edges, free — zero normal slope — on the others). The
//! result is a pure function of the tile and its inputs, so the world stays a pure function
//! of (seed, weights, tile) whatever the visit order.

/// Over-relaxation sweeps of the membrane (a 32² tile converges to < 0.1 % in ~100).
pub const SWEEPS: usize = 160;
/// Over-relaxation factor of the sweeps.
const OMEGA: f32 = 1.85;

/// The sides of a tile, in the order [`join_edges`] takes its neighbours: −x, +x, −z, +z.
pub const SIDES: [(i32, i32); 4] = [(-1, 0), (1, 0), (0, -1), (0, 1)];

/// Moves the edges of `tile` (`n`×`n` heights, row-major, rows along +z) onto the surfaces of
/// its input neighbours (`n`×`n` each, in [`SIDES`] order; `None` where a side was not an
/// input) and spreads the correction smoothly inside. Without neighbours nothing changes.
pub fn join_edges(tile: &mut [f32], n: usize, neighbours: [Option<&[f32]>; 4]) {
    assert_eq!(tile.len(), n * n);
    assert!(n >= 3, "a tile of {n}² samples has no interior");
    if neighbours.iter().all(Option::is_none) {
        return;
    }
    let at = |t: &[f32], u: usize, v: usize| t[v * n + u];
    // The correction each side asks for along its edge: (sample index along the edge → δ).
    let mut fixed: Vec<Option<(f32, u32)>> = vec![None; n * n];
    let mut add = |u: usize, v: usize, d: f32| {
        let slot = &mut fixed[v * n + u];
        let (sum, k) = slot.unwrap_or((0.0, 0));
        *slot = Some((sum + d, k + 1));
    };
    for (side, nb) in neighbours.iter().enumerate() {
        let Some(nb) = nb else { continue };
        assert_eq!(nb.len(), n * n);
        for k in 0..n {
            // (tile's edge sample, the one inside it), (neighbour's facing sample, the one behind it)
            let (own, inner, face, behind) = match side {
                0 => ((0, k), (1, k), (n - 1, k), (n - 2, k)),
                1 => ((n - 1, k), (n - 2, k), (0, k), (1, k)),
                2 => ((k, 0), (k, 1), (k, n - 1), (k, n - 2)),
                _ => ((k, n - 1), (k, n - 2), (k, 0), (k, 1)),
            };
            let slope = 0.5 * ((at(nb, face.0, face.1) - at(nb, behind.0, behind.1)) + (at(tile, inner.0, inner.1) - at(tile, own.0, own.1)));
            let target = at(nb, face.0, face.1) + slope;
            add(own.0, own.1, target - at(tile, own.0, own.1));
        }
    }
    let fixed: Vec<Option<f32>> = fixed.into_iter().map(|s| s.map(|(sum, k)| sum / k as f32)).collect();
    let mut c: Vec<f32> = fixed.iter().map(|f| f.unwrap_or(0.0)).collect();
    for _ in 0..SWEEPS {
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
                *p += OMEGA * (0.25 * (l + r + t + b) - *p);
            }
        }
    }
    for (h, d) in tile.iter_mut().zip(&c) {
        *h += d;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(n: usize, a: f32, b: f32, c0: f32) -> Vec<f32> {
        (0..n * n).map(|p| c0 + a * (p % n) as f32 + b * (p / n) as f32).collect()
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
                // The slope across each edge is the plane's plus half the bump's own slope.
                worst_edge = worst_edge.max((tile[v * n + u] - world(u as i32, v as i32)).abs());
            }
        }
        assert!(worst_edge < 0.5 * 30.0 * 0.3 + 1e-3, "edge sample off the plane by {worst_edge} m");
        let corr: Vec<f32> = tile.iter().zip(&before).map(|(a, b)| a - b).collect();
        let biggest = corr.iter().fold(0f32, |m, c| m.max(c.abs()));
        for v in 1..n - 1 {
            for u in 1..n - 2 {
                let d = (corr[v * n + u + 1] - corr[v * n + u]).abs();
                assert!(d <= biggest / 4.0, "correction jumps {d} m at ({u},{v}), largest {biggest} m");
            }
        }
    }
}
