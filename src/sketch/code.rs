//! A sketch as a short text for share links: one 4-bit code per pixel (band in two bits, ridge,
//! valley), deflated and written in URL-safe base64 without padding. Reading checks every
//! length before allocating and never inflates past one sketch's size.

use std::io::{Read, Write};

use base64::Engine;
use base64::engine::general_purpose::URL_SAFE_NO_PAD;

use super::{SKETCH_PX, Sketch};

/// Bytes of a sketch before deflate (two pixels per byte).
const RAW_BYTES: usize = SKETCH_PX * SKETCH_PX / 2;
/// Longest code accepted (characters): far above any drawn sketch, bounded for hostile links.
pub const MAX_CODE_CHARS: usize = 48 * 1024;

/// Why a text is not a sketch code.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CodeError {
    /// Longer than [`MAX_CODE_CHARS`].
    #[error("the sketch code has {0} characters, more than the {MAX_CODE_CHARS} accepted")]
    TooLong(usize),
    /// Not URL-safe base64.
    #[error("the sketch code is not URL-safe base64")]
    Base64,
    /// Not a deflate stream of exactly one sketch.
    #[error("the sketch code does not hold one {SKETCH_PX}×{SKETCH_PX} sketch")]
    Content,
}

/// The code of `sketch`.
pub fn encode(sketch: &Sketch) -> String {
    let mut raw = vec![0u8; RAW_BYTES];
    for (p, slot) in (0..sketch.band.len()).zip((0..RAW_BYTES).flat_map(|i| [(i, 0), (i, 4)])) {
        let nibble = (sketch.band[p] & 3) | (sketch.ridge[p] as u8) << 2 | (sketch.valley[p] as u8) << 3;
        raw[slot.0] |= nibble << slot.1;
    }
    let mut enc = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::best());
    enc.write_all(&raw).expect("deflate into memory");
    URL_SAFE_NO_PAD.encode(enc.finish().expect("deflate into memory"))
}

/// The sketch of a code made by [`encode`].
pub fn decode(code: &str) -> Result<Sketch, CodeError> {
    if code.len() > MAX_CODE_CHARS {
        return Err(CodeError::TooLong(code.len()));
    }
    let packed = URL_SAFE_NO_PAD.decode(code.trim()).map_err(|_| CodeError::Base64)?;
    let mut raw = Vec::with_capacity(RAW_BYTES);
    // One byte more than a sketch: a longer stream is refused without inflating it further.
    flate2::read::DeflateDecoder::new(packed.as_slice()).take(RAW_BYTES as u64 + 1).read_to_end(&mut raw).map_err(|_| CodeError::Content)?;
    if raw.len() != RAW_BYTES {
        return Err(CodeError::Content);
    }
    let mut s = Sketch::filled(0);
    for p in 0..s.band.len() {
        let nibble = (raw[p / 2] >> (4 * (p % 2))) & 15;
        s.band[p] = nibble & 3;
        s.ridge[p] = nibble & 4 != 0;
        s.valley[p] = nibble & 8 != 0;
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_drawn_sketch_round_trips_in_under_2_kb() {
        let mut c = crate::sketch::canvas::Canvas::default();
        c.set_tool(crate::sketch::canvas::Tool::Band(3));
        c.set_brush_px(40.0);
        c.press(60.0, 60.0);
        c.drag(200.0, 120.0);
        c.release();
        c.set_tool(crate::sketch::canvas::Tool::Ridge);
        c.press(30.0, 200.0);
        c.drag(220.0, 40.0);
        c.release();
        let code = encode(c.sketch());
        assert!(code.len() < 2048, "{} characters", code.len());
        assert_eq!(&decode(&code).unwrap(), c.sketch());
    }

    #[test]
    fn bad_codes_are_errors() {
        assert_eq!(decode("not base64!"), Err(CodeError::Base64));
        assert_eq!(decode(&URL_SAFE_NO_PAD.encode(b"plain bytes")), Err(CodeError::Content));
        assert_eq!(decode(&"A".repeat(MAX_CODE_CHARS + 1)), Err(CodeError::TooLong(MAX_CODE_CHARS + 1)));
        // A stream inflating to twice a sketch is refused (read stops one byte past it).
        let mut enc = flate2::write::DeflateEncoder::new(Vec::new(), flate2::Compression::best());
        enc.write_all(&vec![0u8; 2 * RAW_BYTES]).unwrap();
        assert_eq!(decode(&URL_SAFE_NO_PAD.encode(enc.finish().unwrap())), Err(CodeError::Content));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn random_text_never_panics(s in ".{0,300}") {
            let _ = decode(&s);
        }

        #[test]
        fn random_sketches_round_trip(seed in any::<u64>()) {
            let mut s = Sketch::filled(0);
            let mut x = seed | 1;
            for p in 0..s.band.len() {
                x ^= x << 13; x ^= x >> 7; x ^= x << 17;
                s.band[p] = (x & 3) as u8;
                s.ridge[p] = x & 64 != 0;
                s.valley[p] = x & 128 != 0;
            }
            prop_assert_eq!(decode(&encode(&s)).unwrap(), s);
        }
    }
}
