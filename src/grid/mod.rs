//! The grid every floor above shares: tile coordinates and their relation to metres, the
//! order-free tile schedule (phases and the neighbours each phase is made from), and the two
//! integer hashes of the project — SplitMix64 ([`mix64`]) for seeds and noise, FNV-1a
//! ([`Fnv`]) for checksums and weight hashes. A leaf: it imports nothing of the crate, so
//! `models` and `world` both build on it without either reaching up into the other.

pub mod coord;
pub mod schedule;

pub use coord::{BASE_SPACING_M, TILE_SAMPLES, TILE_SIZE_M, TileCoord};

/// SplitMix64 finaliser: a bijective 64-bit mix.
pub fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// FNV-1a, 64 bits: fed bytes ([`Fnv::bytes`]) or whole words ([`Fnv::word`], one step per
/// 64-bit word). The one implementation behind tile checksums and weight hashes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Fnv(pub u64);

impl Default for Fnv {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    const PRIME: u64 = 0x0000_0100_0000_01b3;

    /// Folds in every byte of `bytes`, in order.
    pub fn bytes(self, bytes: &[u8]) -> Self {
        Self(bytes.iter().fold(self.0, |h, b| (h ^ *b as u64).wrapping_mul(Self::PRIME)))
    }

    /// Folds in one 64-bit word in a single step (as the tile checksum does per height).
    pub fn word(self, w: u64) -> Self {
        Self((self.0 ^ w).wrapping_mul(Self::PRIME))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The published FNV-1a 64 test vectors: "" → cbf29ce484222325, "a" → af63dc4c8601ec8c,
    /// "foobar" → 85944171f73967e8.
    #[test]
    fn fnv_matches_the_published_test_vectors() {
        assert_eq!(Fnv::default().bytes(b"").0, 0xcbf2_9ce4_8422_2325);
        assert_eq!(Fnv::default().bytes(b"a").0, 0xaf63_dc4c_8601_ec8c);
        assert_eq!(Fnv::default().bytes(b"foobar").0, 0x8594_4171_f739_67e8);
        // A byte fed as a word is the same single step.
        assert_eq!(Fnv::default().word(b'a' as u64), Fnv::default().bytes(b"a"));
    }
}
