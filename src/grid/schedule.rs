//! The tile schedule: which neighbours a tile is generated from, as a pure function of its
//! coordinate, so the world never depends on the order in which tiles were visited.
//!
//! Four phases by parity (SPEC.md): phase 0 tiles (even i, even j) use no neighbours; phase 1
//! (odd, even) use their left/right phase-0 neighbours; phase 2 (even, odd) their up/down phase-0
//! neighbours; phase 3 (odd, odd) all eight, which are of phases 0, 1 and 2. Every dependency is
//! of a lower phase, so resolution terminates after at most three levels, and tiles of one phase
//! are independent of each other and can be generated in one batch.

use super::coord::TileCoord;
use super::mix64;

/// Generation phase of a tile, determined by the parity of its coordinate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Phase {
    /// Even i, even j: generated from nothing but the seed.
    Free = 0,
    /// Odd i, even j: generated from the left and right neighbours.
    Horizontal = 1,
    /// Even i, odd j: generated from the up and down neighbours.
    Vertical = 2,
    /// Odd i, odd j: generated from all eight neighbours.
    Centre = 3,
}

/// The four phases in generation order (index = `Phase as usize`).
pub const PHASES: [Phase; 4] = [Phase::Free, Phase::Horizontal, Phase::Vertical, Phase::Centre];

/// The phase of tile `c`.
pub fn phase(c: TileCoord) -> Phase {
    match (c.i.rem_euclid(2), c.j.rem_euclid(2)) {
        (0, 0) => Phase::Free,
        (1, 0) => Phase::Horizontal,
        (0, _) => Phase::Vertical,
        _ => Phase::Centre,
    }
}

/// Offsets (di, dj) of the neighbours a tile of phase `p` is generated from.
pub fn dependency_offsets(p: Phase) -> &'static [(i32, i32)] {
    match p {
        Phase::Free => &[],
        Phase::Horizontal => &[(-1, 0), (1, 0)],
        Phase::Vertical => &[(0, -1), (0, 1)],
        Phase::Centre => &[(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)],
    }
}

/// The neighbours tile `c` is generated from (tile coordinates).
pub fn dependencies(c: TileCoord) -> impl Iterator<Item = TileCoord> {
    dependency_offsets(phase(c)).iter().map(move |&(di, dj)| c.offset(di, dj))
}

/// A 64-bit seed for tile `c` of world `seed`: a strong integer hash, identical on every
/// platform (no floating point involved).
pub fn tile_seed(seed: u64, c: TileCoord) -> u64 {
    let h = mix64(seed ^ 0x9E37_79B9_7F4A_7C15);
    let h = mix64(h ^ (c.i as u32 as u64));
    mix64(h ^ ((c.j as u32 as u64) << 32))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dependencies_are_always_of_a_lower_phase() {
        for i in -4..4 {
            for j in -4..4 {
                let c = TileCoord::new(i, j);
                for d in dependencies(c) {
                    assert!(phase(d) < phase(c), "{c:?} ({:?}) depends on {d:?} ({:?})", phase(c), phase(d));
                }
            }
        }
    }

    #[test]
    fn phase_counts_match_the_parity_scheme() {
        let mut counts = [0usize; 4];
        for i in -10..10 {
            for j in -10..10 {
                counts[phase(TileCoord::new(i, j)) as usize] += 1;
            }
        }
        assert_eq!(counts, [100, 100, 100, 100]);
        assert_eq!(dependencies(TileCoord::new(1, 1)).count(), 8);
        assert_eq!(dependencies(TileCoord::new(-1, 0)).collect::<Vec<_>>(), vec![TileCoord::new(-2, 0), TileCoord::new(0, 0)]);
    }

    /// 1024 seeds of 4 worlds × 16² tiles are all distinct, and every one of the 64 bits is
    /// set in 40–60 % of them (well mixed: neighbouring tiles and worlds share no structure).
    #[test]
    fn tile_seeds_are_distinct_and_well_mixed() {
        let mut seen = std::collections::HashSet::new();
        let mut ones = [0u32; 64];
        for s in 0..4u64 {
            for i in -8..8 {
                for j in -8..8 {
                    let t = tile_seed(s, TileCoord::new(i, j));
                    assert!(seen.insert(t), "seed collision at world {s}, tile ({i},{j})");
                    for (b, n) in ones.iter_mut().enumerate() {
                        *n += (t >> b & 1) as u32;
                    }
                }
            }
        }
        for (b, &n) in ones.iter().enumerate() {
            assert!((410..=614).contains(&n), "bit {b} set in {n} of 1024 seeds");
        }
    }
}
