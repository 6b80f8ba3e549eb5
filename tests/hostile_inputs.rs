//! Hostile inputs: forged headers, truncated and mutated files, random bytes and random share
//! links. Every bad input is a clear error — never a panic, never unbounded memory. Memory is
//! measured with a counting allocator (this test binary's own), so "bounded" is a number.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Cursor;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use proptest::prelude::*;
use terrain::dem::{DemError, Heightfield, PngScale};
use terrain::share::ShareState;

/// Counts live bytes and the peak since the last reset.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            let now = LIVE.fetch_add(l.size(), Ordering::Relaxed) + l.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) };
        LIVE.fetch_sub(l.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// Tests that measure memory run one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

/// Runs `f` and returns its result and the most bytes it held at once beyond what was live
/// before.
fn peak_of<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let out = f();
    (out, PEAK.load(Ordering::Relaxed).saturating_sub(base))
}

const MIB: usize = 1 << 20;

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// A valid 16-bit grey PNG of `w × h` samples.
fn png16(w: u32, h: u32) -> Vec<u8> {
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, w, h);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let mut wr = enc.write_header().unwrap();
        let data: Vec<u8> = (0..w * h).flat_map(|k| ((k * 37 % 4000) as u16).to_be_bytes()).collect();
        wr.write_image_data(&data).unwrap();
    }
    bytes
}

/// `png` with its IHDR claiming `w × h` (CRC fixed, so only the size lies).
fn forge_png_size(mut png: Vec<u8>, w: u32, h: u32) -> Vec<u8> {
    // Signature (8), IHDR length (4), "IHDR" (4), width, height…, CRC over type + data.
    png[16..20].copy_from_slice(&w.to_be_bytes());
    png[20..24].copy_from_slice(&h.to_be_bytes());
    let crc = crc32(&png[12..29]);
    png[29..33].copy_from_slice(&crc.to_be_bytes());
    png
}

/// A valid float32 GeoTIFF of `w × h` samples.
fn tiff32(w: usize, h: usize) -> Vec<u8> {
    let hf = Heightfield::new(w, h, 30.0, (0..w * h).map(|k| k as f32 * 0.5).collect());
    let mut buf = Cursor::new(Vec::new());
    hf.write_tiff(&mut buf).unwrap();
    buf.into_inner()
}

/// `tiff` (little-endian) with ImageWidth/ImageLength set to `w × h`.
fn forge_tiff_size(mut t: Vec<u8>, w: u32, h: u32) -> Vec<u8> {
    let ifd = u32::from_le_bytes(t[4..8].try_into().unwrap()) as usize;
    let n = u16::from_le_bytes(t[ifd..ifd + 2].try_into().unwrap()) as usize;
    for e in 0..n {
        let at = ifd + 2 + 12 * e;
        let tag = u16::from_le_bytes(t[at..at + 2].try_into().unwrap());
        let kind = u16::from_le_bytes(t[at + 2..at + 4].try_into().unwrap());
        let v = match tag {
            256 => w,
            257 => h,
            _ => continue,
        };
        // SHORT (3) values sit in the first two bytes of the value field, LONG (4) in four.
        t[at + 4..at + 8].copy_from_slice(&1u32.to_le_bytes());
        t[at + 2..at + 4].copy_from_slice(&4u16.to_le_bytes());
        let _ = kind;
        t[at + 8..at + 12].copy_from_slice(&v.to_le_bytes());
    }
    t
}

/// PNGs whose headers claim up to 16384² samples (the old reader allocated the whole image
/// first: 512 MiB at 16 bits) but hold 6 bytes of data, each refused for the reason it
/// deserves, holding under 4 MiB: over the 2²⁶-sample cap (16384², 8193 × 8192) as too
/// large; at or under it (8192², 4096²) as more data than the file can hold; a small claim
/// (65535×1, 128 KiB) is decoded and runs out of data.
#[test]
fn a_forged_png_size_is_refused_before_allocating() {
    let _s = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let cases = [
        (16_384, 16_384, "is larger than the 67108864 samples"),
        (8193, 8192, "is larger than"),
        (8192, 8192, "it is truncated or its header is wrong"),
        (4096, 4096, "it is truncated or its header is wrong"),
        (65_535, 1, "not have enough data"),
    ];
    for (w, h, why) in cases {
        let bytes = forge_png_size(png16(3, 1), w, h);
        let (r, peak) = peak_of(|| Heightfield::read_png(Cursor::new(bytes.clone()), PngScale::default(), 1.0));
        let e = r.unwrap_err().to_string();
        assert!(e.contains(why), "{w}×{h}: {e}");
        assert!(peak < 4 * MIB, "{w}×{h}: held {peak} bytes");
    }
}

/// A TIFF whose tags claim 30000² or 8193 × 8192 samples with 24 bytes of data is refused
/// as over the 2²⁶-sample cap; one claiming 8000² or 2000² (under the cap) as more data than
/// the file holds; holding under 4 MiB.
#[test]
fn a_forged_tiff_size_is_refused_before_allocating() {
    let _s = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let cases = [
        (30_000, 30_000, "is larger than the 67108864 samples"),
        (8193, 8192, "is larger than"),
        (8000, 8000, "it is truncated or its header is wrong"),
        (2000, 2000, "it is truncated or its header is wrong"),
    ];
    for (w, h, why) in cases {
        let bytes = forge_tiff_size(tiff32(3, 2), w, h);
        let (r, peak) = peak_of(|| Heightfield::read_tiff(Cursor::new(bytes.clone()), 1.0));
        let e = r.unwrap_err().to_string();
        assert!(e.contains(why), "{w}×{h}: {e}");
        assert!(peak < 4 * MIB, "{w}×{h}: held {peak} bytes");
    }
}

/// Sample formats that are not heightfields are named in the error: RGB TIFF, palette PNG,
/// infinite heights.
#[test]
fn wrong_sample_formats_are_clear_errors() {
    let mut rgb = Cursor::new(Vec::new());
    {
        let mut enc = tiff::encoder::TiffEncoder::new(&mut rgb).unwrap();
        enc.write_image::<tiff::encoder::colortype::RGB8>(2, 2, &[0u8; 12]).unwrap();
    }
    rgb.set_position(0);
    let e = Heightfield::read_tiff(rgb, 1.0).unwrap_err().to_string();
    assert!(e.contains("multi-band"), "{e}");
    let mut pal = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut pal, 2, 1);
        enc.set_color(png::ColorType::Indexed);
        enc.set_palette(vec![0u8, 0, 0, 255, 255, 255]);
        enc.write_header().unwrap().write_image_data(&[0, 1]).unwrap();
    }
    let e = Heightfield::read_png(Cursor::new(pal), PngScale::default(), 1.0).unwrap_err().to_string();
    assert!(e.contains("not a heightmap"), "{e}");
    let inf = Heightfield::new(2, 1, 1.0, vec![1.0, f32::INFINITY]).validate().unwrap_err();
    assert!(matches!(inf, DemError::Invalid(_)) && inf.to_string().contains("inf"), "{inf}");
}

/// The coverage-guided fuzzer's (fuzz/) first finding: a TIFF whose SampleFormat tag holds no
/// values made the tiff decoder (0.10) index an empty list and panic. It is an error now.
#[test]
fn a_tiff_with_an_empty_sample_format_tag_is_an_error_not_a_panic() {
    use base64::Engine;
    let bytes = base64::engine::general_purpose::STANDARD
        .decode("SUkqAAgAAAANAAABBAABAAAAEAAAAAEBBAABAAAAEAAAAAIBAwABAAAAIAAAAAMBAwABAAAAAQAAAAYBAwABAAAAAQAAABEBBAABAAAAEgEAABYBEAAAAAEABAAAABcBBAABAAAAAAQAABwBAwABAAAAAQAAAFMBAwAAAAAAAwAAAA6DDAAD+638KyYlRBrT2HNEje93RE+Te0Q8XX5Euv5/ROokgERHMH9EZ+J8RMyPeUQcnHVEtXZxRHGUbUTCYmpErjtoRN9bZ0T422dE")
        .unwrap();
    let e = std::panic::catch_unwind(|| Heightfield::read_tiff(Cursor::new(bytes), 1.0)).expect("the reader panicked").unwrap_err();
    assert!(!e.to_string().is_empty());
}

/// Runs every reader on `bytes`: each must return (Ok or a non-empty error) without panicking
/// and hold at most `limit` bytes.
fn read_all_ways(bytes: &[u8], limit: usize) -> Result<(), TestCaseError> {
    let (results, peak) = peak_of(|| {
        let t = Heightfield::read_tiff(Cursor::new(bytes.to_vec()), 1.0).map(|h| h.width);
        let p = Heightfield::read_png(Cursor::new(bytes.to_vec()), PngScale::default(), 1.0).map(|h| h.width);
        [t, p]
    });
    for r in results {
        if let Err(e) = r {
            prop_assert!(!e.to_string().is_empty());
        }
    }
    prop_assert!(peak <= limit, "held {} bytes for {} input bytes", peak, bytes.len());
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, failure_persistence: None, ..ProptestConfig::default() })]

    /// Random bytes (with and without a PNG or TIFF signature in front).
    #[test]
    fn random_bytes_never_panic_or_balloon(body in proptest::collection::vec(any::<u8>(), 0..2048), head in 0usize..3) {
        let _s = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
        let mut bytes = match head { 0 => Vec::new(), 1 => b"\x89PNG\r\n\x1a\n".to_vec(), _ => b"II*\0".to_vec() };
        bytes.extend(body);
        read_all_ways(&bytes, 8 * MIB)?;
    }

    /// Real files (a 16-bit PNG, a GeoTIFF, the terrain-RGB fixture) with bytes flipped and
    /// the tail cut off.
    #[test]
    fn mutated_real_files_never_panic_or_balloon(which in 0usize..3, flips in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8), cut in any::<prop::sample::Index>()) {
        let _s = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
        let mut bytes = match which {
            0 => png16(40, 30),
            1 => tiff32(40, 30),
            _ => std::fs::read(terrain::repo_root().join("../shared/fixtures/fuji_terrain_rgb.png")).unwrap(),
        };
        for (i, v) in flips {
            let k = i.index(bytes.len());
            bytes[k] ^= v;
        }
        let keep = cut.index(bytes.len() + 1).max(bytes.len() / 2);
        bytes.truncate(keep);
        read_all_ways(&bytes, 64 * MIB)?;
    }

    /// Any string as a fragment: an error or a state whose camera is finite and whose values
    /// are in their documented ranges; never a panic.
    #[test]
    fn any_fragment_is_a_state_or_an_error(f in ".{0,200}") {
        check_fragment(&f)?;
    }

    /// Fragments made of the link's own keys with random values (numbers, huge, NaN, encoded).
    #[test]
    fn link_shaped_fragments_are_states_or_errors(
        parts in proptest::collection::vec((prop::sample::select(vec!["v", "seed", "cam", "r", "lod", "noise", "auto", "x"]), "[-+0-9.,eE%a-z]{0,40}"), 0..8)
    ) {
        let f: Vec<String> = parts.iter().map(|(k, v)| format!("{k}={v}")).collect();
        check_fragment(&f.join("&"))?;
    }

    /// Valid states survive the round trip through a link: every setting bit for bit, the
    /// camera to the centimetre and its angles to 6·10⁻⁶ rad (10⁻⁵ rad rounding of an f32); the link read back writes the same link.
    #[test]
    fn valid_states_round_trip_exactly_but_the_camera_to_the_centimetre(seed in any::<u64>(), x in -1e8f64..1e8, y in -1e4f64..1e5, z in -1e8f64..1e8, yaw in 0f32..std::f32::consts::TAU, pitch in -1.55f32..1.55, r in 1f64..16.0, lod in 0.5f64..64.0, auto in 0f64..5000.0) {
        let s = ShareState { seed, position_m: [x, y, z], yaw, pitch, radius_tiles: r, lod_px: lod, autopilot_mps: auto, ..ShareState::default() };
        let link = s.to_fragment();
        let back = ShareState::from_fragment(&link).unwrap();
        prop_assert!(back.position_m.iter().zip(&s.position_m).all(|(a, b)| (a - b).abs() <= 0.005), "{:?} vs {:?}", back.position_m, s.position_m);
        prop_assert!((back.yaw - s.yaw).abs() <= 6e-6 && (back.pitch - s.pitch).abs() <= 6e-6, "{} {} vs {} {}", back.yaw, back.pitch, s.yaw, s.pitch);
        prop_assert_eq!(back.to_fragment(), link);
        prop_assert_eq!(ShareState { position_m: s.position_m, yaw: s.yaw, pitch: s.pitch, ..back }, s);
    }
}

fn check_fragment(f: &str) -> Result<(), TestCaseError> {
    match ShareState::from_fragment(f) {
        Ok(s) => {
            prop_assert!(s.position_m.iter().all(|c| c.is_finite() && c.abs() <= 1e9));
            prop_assert!(s.yaw.is_finite() && s.pitch.is_finite() && s.pitch.abs() <= 1.55);
            prop_assert!((1.0..=16.0).contains(&s.radius_tiles) && (0.5..=64.0).contains(&s.lod_px));
            prop_assert!(s.noise.validate().is_ok() && (0.0..=5000.0).contains(&s.autopilot_mps));
        }
        Err(e) => prop_assert!(!e.to_string().is_empty()),
    }
    Ok(())
}
