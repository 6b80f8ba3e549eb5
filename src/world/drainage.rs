//! Drainage: filling closed depressions so that water from every sample can run off the
//! tile's border.
//!
//! Real terrain drains; a generator's output (and noise) is full of small pits. The fill is
//! priority-flood with an ε gradient (Barnes, Lehman & Mulla 2014): the border samples keep
//! their heights and are the outlets; every other sample is raised, if needed, to just above
//! the lowest height at which it can spill to the border through its 4 neighbours. A filled
//! lake becomes a surface rising by [`FLAT_GRADIENT_M`] per sample away from its outlet, so
//! every sample has a strictly descending 4-connected path to the border.
//!
//! The border is never changed, so filling one tile changes nothing along the edges it shares
//! with its neighbours, and a filled tile is still a pure function of its input.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Rise (metres per sample) given to filled flats so that they drain.
pub const FLAT_GRADIENT_M: f32 = 1e-3;

#[derive(PartialEq, PartialOrd)]
struct Height(f32);
impl Eq for Height {}
impl Ord for Height {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0)
    }
}

/// Fills the closed depressions of the `n`×`n` heightfield `h` (metres, row-major) in place,
/// its border fixed. Each filled sample is raised to at least `gradient_m` (rounded up to the
/// next representable height) above the sample it drains to; 0 makes level lakes. NaN samples
/// are left as they are and do not drain. Returns the number of samples raised.
pub fn fill_depressions(h: &mut [f32], n: usize, gradient_m: f32) -> usize {
    assert_eq!(h.len(), n * n, "a {n}×{n} field has {} samples, not {}", n * n, h.len());
    let mut done = vec![false; n * n];
    let mut heap = BinaryHeap::new();
    // The sequence number keeps the order of equal heights fixed (first in, first out), so
    // the ε surface does not depend on the heap's tie-breaking.
    let mut seq = 0u64;
    for i in 0..n {
        for p in [i, (n - 1) * n + i, i * n, i * n + n - 1] {
            if !done[p] && !h[p].is_nan() {
                done[p] = true;
                heap.push(Reverse((Height(h[p]), seq, p)));
                seq += 1;
            }
        }
    }
    let mut raised = 0;
    while let Some(Reverse((Height(z), _, p))) = heap.pop() {
        let (x, y) = (p % n, p / n);
        for (qx, qy) in [(x.wrapping_sub(1), y), (x + 1, y), (x, y.wrapping_sub(1)), (x, y + 1)] {
            if qx >= n || qy >= n {
                continue;
            }
            let q = qy * n + qx;
            if done[q] || h[q].is_nan() {
                continue;
            }
            done[q] = true;
            let floor = if gradient_m > 0.0 { above(z, gradient_m) } else { z };
            if h[q] < floor {
                h[q] = floor;
                raised += 1;
            }
            heap.push(Reverse((Height(h[q]), seq, q)));
            seq += 1;
        }
    }
    raised
}

/// `z + d`, or the next representable value above `z` where `d` is below its precision.
fn above(z: f32, d: f32) -> f32 {
    let s = z + d;
    if s > z { s } else { z.next_up() }
}

/// Fraction of the `n`×`n` field `h` lying in closed depressions deeper than `depth_m`: the
/// samples that a level fill ([`fill_depressions`] with no gradient) raises by more than it.
pub fn depression_fraction(h: &[f32], n: usize, depth_m: f32) -> f64 {
    let mut filled = h.to_vec();
    fill_depressions(&mut filled, n, 0.0);
    filled.iter().zip(h).filter(|(f, o)| **f - **o > depth_m).count() as f64 / (n * n) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether every sample of `h` has a strictly descending 4-connected path to the border
    /// (found by walking from the border upwards).
    fn drains(h: &[f32], n: usize) -> bool {
        let mut ok = vec![false; n * n];
        let mut stack: Vec<usize> = (0..n * n).filter(|p| p % n == 0 || p % n == n - 1 || p / n == 0 || p / n == n - 1).collect();
        stack.iter().for_each(|&p| ok[p] = true);
        while let Some(p) = stack.pop() {
            let (x, y) = (p % n, p / n);
            for (qx, qy) in [(x.wrapping_sub(1), y), (x + 1, y), (x, y.wrapping_sub(1)), (x, y + 1)] {
                if qx < n && qy < n && !ok[qy * n + qx] && h[qy * n + qx] > h[p] {
                    ok[qy * n + qx] = true;
                    stack.push(qy * n + qx);
                }
            }
        }
        ok.iter().all(|&o| o)
    }

    fn noise(n: usize, seed: u64) -> Vec<f32> {
        (0..n * n).map(|p| (crate::world::schedule::mix64(seed ^ p as u64) % 10_000) as f32 * 0.01 + 2000.0).collect()
    }

    /// White noise (100 m range at 2 km) is full of pits; after the fill every sample drains
    /// strictly to the border, the border is bit-identical and no sample went down.
    #[test]
    fn filled_noise_drains_everywhere_and_keeps_its_border() {
        let n = 64;
        let h0 = noise(n, 7);
        assert!(!drains(&h0, n));
        let mut h = h0.clone();
        let raised = fill_depressions(&mut h, n, FLAT_GRADIENT_M);
        assert!(raised > 100, "{raised}");
        assert!(drains(&h, n));
        for p in 0..n * n {
            assert!(h[p] >= h0[p]);
            if p % n == 0 || p % n == n - 1 || p / n == 0 || p / n == n - 1 {
                assert_eq!(h[p].to_bits(), h0[p].to_bits());
            }
        }
        assert_eq!(depression_fraction(&h, n, 0.0), 0.0);
    }

    /// A bowl 10 m deep whose rim is lowered at one border sample fills to its spill height
    /// (the height of the bowl's sample beside that border sample, 109.375 m), within the ε
    /// gradient over the bowl's radius; a plane is left as it is.
    #[test]
    fn a_bowl_fills_to_its_spill_height_and_a_plane_is_unchanged() {
        let n = 33;
        let c = 16.0f32;
        let mut h: Vec<f32> = (0..n * n).map(|p| 100.0 + (((p % n) as f32 - c).powi(2) + ((p / n) as f32 - c).powi(2)).sqrt().min(c) * 10.0 / c).collect();
        h[16] = 109.0; // the spill point on the top border
        let before = h.clone();
        fill_depressions(&mut h, n, FLAT_GRADIENT_M);
        let spill = before[n + 16];
        assert_eq!(spill, 109.375);
        let centre = h[16 * n + 16];
        assert!(centre >= spill && centre <= spill + 17.0 * FLAT_GRADIENT_M, "{centre}");
        assert!((depression_fraction(&before, n, 0.5) - before.iter().filter(|&&v| v < spill - 0.5).count() as f64 / (n * n) as f64).abs() < 1e-12);
        let mut plane: Vec<f32> = (0..n * n).map(|p| (p % n) as f32 * 2.0).collect();
        let p0 = plane.clone();
        assert_eq!(fill_depressions(&mut plane, n, FLAT_GRADIENT_M), 0);
        assert_eq!(plane, p0);
    }
}
