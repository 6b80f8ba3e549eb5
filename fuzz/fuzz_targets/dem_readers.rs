//! Fuzz target: any bytes through every DEM reader a user's file meets (TIFF/GeoTIFF, 16-bit
//! PNG, terrain-RGB PNG). Each must return a heightfield or an error: a panic, or memory past
//! libFuzzer's RSS limit, is a finding.
#![no_main]

use std::io::Cursor;

use libfuzzer_sys::fuzz_target;

/// The app's readers, compiled from the app's own source file.
#[allow(dead_code, missing_docs)]
#[path = "../../src/dem/mod.rs"]
mod dem;

use dem::{Heightfield, PngScale};

fuzz_target!(|data: &[u8]| {
    // read_png takes 16-bit grey and terrain-RGB (by the file's colour type).
    let read = [Heightfield::read_tiff(Cursor::new(data), 1.0), Heightfield::read_png(Cursor::new(data), PngScale::default(), 1.0)];
    for hf in read.into_iter().flatten() {
        // What a reader returns is whole: every sample of the size it claims.
        assert_eq!(hf.data.len(), hf.width * hf.height);
    }
});
