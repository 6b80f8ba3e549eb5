//! Sketches: a topographic map drawn as four level-set bands (green), ridge strokes (red) and
//! valley strokes (blue), the input of sketch-to-terrain (../shared/SKETCH_FORMAT.md).
//!
//! A [`Sketch`] is [`SKETCH_PX`]² pixels; each pixel has a band 0..=3 (low → high) and may carry
//! a ridge and/or a valley stroke. It reads and writes the format's palette PNG ([`Sketch::read_png`],
//! [`Sketch::write_png`]). [`extract`] makes sketches from real DEMs, [`baseline`] turns a
//! sketch into heights without learning, [`score`] compares heights on the format's 0–255 scale.

pub mod baseline;
pub mod calibrate;
pub mod canvas;
pub mod code;
pub mod distance;
pub mod examples;
pub mod extract;
mod regions;
pub mod score;
pub mod tidy;

use std::io::{BufRead, Seek, Write};

/// Side of a sketch and of the DEM made from it (pixels).
pub const SKETCH_PX: usize = 256;
/// Number of level-set bands.
pub const BANDS: usize = 4;
/// Green value of each band in the palette (darker = lower).
pub const BAND_GREEN: [u8; BANDS] = [63, 127, 191, 255];
/// Width of a ridge or valley stroke at [`SKETCH_PX`] (pixels), as the authors drew them.
pub const STROKE_PX: usize = 3;

/// Why a file or buffer is not a sketch.
#[derive(Debug, thiserror::Error)]
pub enum SketchError {
    /// The file could not be read or written.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The bytes are not a PNG the reader accepts.
    #[error("not a sketch PNG: {0}")]
    Format(String),
    /// The image is the wrong size.
    #[error("a sketch is {SKETCH_PX}×{SKETCH_PX} pixels; this image is {0}×{1}")]
    Size(u32, u32),
    /// The image decodes, but its colours are not the sketch palette.
    #[error("not a sketch: {0}")]
    Palette(String),
}

/// One sketch: per pixel (row-major, [`SKETCH_PX`]²) a band 0..=3 and the two stroke layers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Sketch {
    /// Level-set band per pixel, 0 (lowest) ..= 3 (highest).
    pub band: Vec<u8>,
    /// Ridge stroke per pixel.
    pub ridge: Vec<bool>,
    /// Valley stroke per pixel.
    pub valley: Vec<bool>,
}

impl Sketch {
    /// A sketch of one band everywhere and no strokes.
    pub fn filled(band: u8) -> Self {
        let n = SKETCH_PX * SKETCH_PX;
        Self { band: vec![band.min(3); n], ridge: vec![false; n], valley: vec![false; n] }
    }

    /// Decodes one RGB pixel with the format's rule: band = the nearest band green, ridge =
    /// R ≥ 128, valley = B ≥ 128.
    pub fn decode_pixel(rgb: [u8; 3]) -> (u8, bool, bool) {
        let band = (0..BANDS).min_by_key(|&k| (BAND_GREEN[k] as i32 - rgb[1] as i32).abs()).unwrap_or(0) as u8;
        (band, rgb[0] >= 128, rgb[2] >= 128)
    }

    /// The palette colour of a band with or without strokes.
    pub fn encode_pixel(band: u8, ridge: bool, valley: bool) -> [u8; 3] {
        [if ridge { 255 } else { 0 }, BAND_GREEN[band.min(3) as usize], if valley { 255 } else { 0 }]
    }

    /// A sketch from [`SKETCH_PX`]² RGB pixels (row-major, 3 bytes each). The image must be a
    /// sketch: green everywhere (no grey, white or black background), so an ordinary photo or
    /// heightmap is refused with a message.
    pub fn from_rgb(rgb: &[u8]) -> Result<Self, SketchError> {
        let n = SKETCH_PX * SKETCH_PX;
        if rgb.len() != 3 * n {
            return Err(SketchError::Palette(format!("{} bytes of RGB for {n} pixels", rgb.len())));
        }
        // A sketch pixel is green-dominant or a stroke over green: its green is at least the
        // darkest band's minus the tolerance of an antialiased edge. Grey heightmaps (R = G = B
        // with no strokes) and photos fail this on most pixels.
        let mut off_palette = 0usize;
        let mut s = Self::filled(0);
        for p in 0..n {
            let px = [rgb[3 * p], rgb[3 * p + 1], rgb[3 * p + 2]];
            let (band, ridge, valley) = Self::decode_pixel(px);
            let stroke = ridge || valley;
            let r_ok = px[0] < 64 || px[0] > 191;
            let b_ok = px[2] < 64 || px[2] > 191;
            let g_ok = px[1] >= 32;
            let grey = !stroke && px[0] == px[1] && px[1] == px[2];
            if !(r_ok && b_ok && g_ok) || grey {
                off_palette += 1;
            }
            s.band[p] = band;
            s.ridge[p] = ridge;
            s.valley[p] = valley;
        }
        // Up to 5 % of pixels may be off the palette (an antialiased hand drawing).
        if off_palette * 20 > n {
            return Err(SketchError::Palette(format!(
                "{:.0} % of its pixels are not sketch colours (green bands G ∈ {{63, 127, 191, 255}}, red ridges, blue valleys)",
                100.0 * off_palette as f64 / n as f64
            )));
        }
        Ok(s)
    }

    /// The sketch as one byte per pixel (row-major): band | ridge << 2 | valley << 3. The
    /// compact form the worker protocol carries ([`crate::jobs::protocol`]).
    pub fn packed(&self) -> Vec<u8> {
        (0..self.band.len()).map(|p| self.band[p].min(3) | (self.ridge[p] as u8) << 2 | (self.valley[p] as u8) << 3).collect()
    }

    /// Reads [`Sketch::packed`] bytes: exactly [`SKETCH_PX`]² of them, each below 16.
    pub fn from_packed(bytes: &[u8]) -> Result<Self, SketchError> {
        let n = SKETCH_PX * SKETCH_PX;
        if bytes.len() != n {
            return Err(SketchError::Palette(format!("{} packed pixels for {n}", bytes.len())));
        }
        if let Some(p) = bytes.iter().position(|&b| b >= 16) {
            return Err(SketchError::Palette(format!("packed pixel {p} is {} (at most 15)", bytes[p])));
        }
        Ok(Self { band: bytes.iter().map(|b| b & 3).collect(), ridge: bytes.iter().map(|b| b & 4 != 0).collect(), valley: bytes.iter().map(|b| b & 8 != 0).collect() })
    }

    /// The sketch as RGB bytes in the palette (row-major, 3 bytes per pixel).
    pub fn to_rgb(&self) -> Vec<u8> {
        (0..self.band.len()).flat_map(|p| Self::encode_pixel(self.band[p], self.ridge[p], self.valley[p])).collect()
    }

    /// Reads a [`SKETCH_PX`]² sketch PNG (8-bit RGB or RGBA; alpha is ignored).
    pub fn read_png<R: BufRead + Seek>(input: R) -> Result<Self, SketchError> {
        let rgb = read_rgb(input, SKETCH_PX, SketchError::Size)?;
        Self::from_rgb(&rgb)
    }

    /// Reads a sketch PNG from a file.
    pub fn read_path(path: &std::path::Path) -> Result<Self, SketchError> {
        Self::read_png(std::io::BufReader::new(std::fs::File::open(path)?))
    }

    /// Writes the sketch as an 8-bit RGB PNG in the palette.
    pub fn write_png<W: Write>(&self, out: W) -> Result<(), SketchError> {
        write_rgb_png(out, SKETCH_PX as u32, SKETCH_PX as u32, &self.to_rgb())
    }

    /// The network's view of the sketch, channel-first ([`INPUT_CHANNELS`] × [`SKETCH_PX`]²):
    /// band / 3, ridge (0/1), valley (0/1).
    pub fn channels(&self) -> Vec<f32> {
        let n = self.band.len();
        let mut x = vec![0f32; INPUT_CHANNELS * n];
        for p in 0..n {
            x[p] = self.band[p] as f32 / 3.0;
            x[n + p] = self.ridge[p] as u8 as f32;
            x[2 * n + p] = self.valley[p] as u8 as f32;
        }
        x
    }

    /// The sketch back from [`Self::channels`] (at least the first [`INPUT_CHANNELS`] ×
    /// n² values of a channel-first stack; n² pixels): band = 3 × the first channel rounded,
    /// ridge and valley where their channels exceed one half.
    pub fn from_channels(x: &[f32], n: usize) -> Self {
        let px = n * n;
        Self {
            band: x[..px].iter().map(|v| ((v * 3.0).round() as u8).min(BANDS as u8 - 1)).collect(),
            ridge: x[px..2 * px].iter().map(|&v| v > 0.5).collect(),
            valley: x[2 * px..3 * px].iter().map(|&v| v > 0.5).collect(),
        }
    }

    /// Fraction of pixels on a ridge and on a valley stroke.
    pub fn stroke_cover(&self) -> (f64, f64) {
        let n = self.band.len() as f64;
        (self.ridge.iter().filter(|&&r| r).count() as f64 / n, self.valley.iter().filter(|&&v| v).count() as f64 / n)
    }
}

/// Channels of [`Sketch::channels`].
pub const INPUT_CHANNELS: usize = 3;

/// Writes 8-bit RGB bytes as a PNG.
pub fn write_rgb_png<W: Write>(out: W, w: u32, h: u32, rgb: &[u8]) -> Result<(), SketchError> {
    let mut enc = png::Encoder::new(out, w, h);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(|e| SketchError::Format(e.to_string()))?;
    writer.write_image_data(rgb).map_err(|e| SketchError::Format(e.to_string()))?;
    writer.finish().map_err(|e| SketchError::Format(e.to_string()))
}

/// Writes relative heights (any range) as the format's 16-bit grey PNG: the lowest sample is 0
/// and the highest 65535 (a flat field is all 0).
pub fn write_dem_png16<W: Write>(out: W, side: usize, heights: &[f32]) -> Result<(), SketchError> {
    let (lo, hi) = heights.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    let span = if hi > lo { hi - lo } else { 1.0 };
    let bytes: Vec<u8> = heights.iter().flat_map(|&v| (((v - lo) / span * 65535.0).round().clamp(0.0, 65535.0) as u16).to_be_bytes()).collect();
    let mut enc = png::Encoder::new(out, side as u32, side as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Sixteen);
    let mut writer = enc.write_header().map_err(|e| SketchError::Format(e.to_string()))?;
    writer.write_image_data(&bytes).map_err(|e| SketchError::Format(e.to_string()))?;
    writer.finish().map_err(|e| SketchError::Format(e.to_string()))
}

/// One of the sketch authors' pairs: a 512×256 RGB PNG, sketch on the left, the 8-bit
/// normalised DEM on the right. Returns the sketch and the DEM on the 0–255 scale.
pub fn read_pair<R: BufRead + Seek>(input: R) -> Result<(Sketch, Vec<f32>), SketchError> {
    let pair = read_rgb(input, 2 * SKETCH_PX, |w, h| SketchError::Format(format!("a pair is {}×{SKETCH_PX} pixels (sketch | DEM); this image is {w}×{h}", 2 * SKETCH_PX)))?;
    let n = SKETCH_PX * SKETCH_PX;
    let mut rgb = Vec::with_capacity(3 * n);
    let mut dem = Vec::with_capacity(n);
    for (p, px) in pair.chunks_exact(3).enumerate() {
        if p % (2 * SKETCH_PX) < SKETCH_PX {
            rgb.extend_from_slice(px);
        } else {
            dem.push(px[1] as f32);
        }
    }
    Ok((Sketch::from_rgb(&rgb)?, dem))
}

/// The 8-bit RGB pixels (alpha dropped) of a PNG that must be `width` × [`SKETCH_PX`]; its
/// size is checked before any pixel buffer is allocated (`size_error` words the refusal).
fn read_rgb<R: BufRead + Seek>(input: R, width: usize, size_error: impl Fn(u32, u32) -> SketchError) -> Result<Vec<u8>, SketchError> {
    let mut decoder = png::Decoder::new(input);
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| SketchError::Format(e.to_string()))?;
    let (w, h) = (reader.info().width, reader.info().height);
    if (w as usize, h as usize) != (width, SKETCH_PX) {
        return Err(size_error(w, h));
    }
    let size = reader.output_buffer_size().ok_or_else(|| SketchError::Format("image too large".into()))?;
    let mut buf = vec![0u8; size];
    let frame = reader.next_frame(&mut buf).map_err(|e| SketchError::Format(e.to_string()))?;
    let channels = match frame.color_type {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        other => return Err(SketchError::Palette(format!("a {other:?} PNG has no colour: a sketch is RGB"))),
    };
    Ok(buf[..frame.buffer_size()].chunks_exact(channels).flat_map(|c| [c[0], c[1], c[2]]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_sixteen_palette_colours_round_trip_through_decode() {
        for band in 0..4u8 {
            for (ridge, valley) in [(false, false), (true, false), (false, true), (true, true)] {
                let rgb = Sketch::encode_pixel(band, ridge, valley);
                assert_eq!(Sketch::decode_pixel(rgb), (band, ridge, valley), "{rgb:?}");
            }
        }
        // Antialiased values decode to the nearest band and threshold the strokes at 128.
        assert_eq!(Sketch::decode_pixel([130, 100, 90]), (1, true, false));
    }

    #[test]
    fn png_round_trip_keeps_every_pixel_and_wrong_sizes_are_refused() {
        let mut s = Sketch::filled(1);
        for p in 0..s.band.len() {
            s.band[p] = ((p / 7) % 4) as u8;
            s.ridge[p] = p % 11 == 0;
            s.valley[p] = p % 13 == 0;
        }
        let mut bytes = Vec::new();
        s.write_png(&mut bytes).unwrap();
        assert_eq!(Sketch::read_png(std::io::Cursor::new(&bytes)).unwrap(), s);

        let mut small = Vec::new();
        write_rgb_png(&mut small, 128, 128, &vec![0u8; 128 * 128 * 3]).unwrap();
        let err = Sketch::read_png(std::io::Cursor::new(&small)).unwrap_err();
        assert!(matches!(err, SketchError::Size(128, 128)), "{err}");
    }

    #[test]
    fn a_grey_heightmap_is_refused_as_not_a_sketch() {
        let grey: Vec<u8> = (0..SKETCH_PX * SKETCH_PX).flat_map(|p| [(p % 256) as u8; 3]).collect();
        let err = Sketch::from_rgb(&grey).unwrap_err();
        assert!(matches!(err, SketchError::Palette(_)), "{err}");
    }
}
