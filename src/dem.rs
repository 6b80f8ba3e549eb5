//! Heightfields: a grid of heights in metres with its sample spacing, and TIFF IO.

use std::io::{Read, Seek, Write};

use tiff::decoder::{Decoder, DecodingResult};
use tiff::encoder::{TiffEncoder, colortype};
use tiff::tags::Tag;

/// A rectangular grid of heights (metres), row-major, row 0 at the north (lowest z), with
/// `spacing_m` metres between neighbouring samples. NaN marks missing data.
#[derive(Clone, Debug, PartialEq)]
pub struct Heightfield {
    /// Samples per row (pixels).
    pub width: usize,
    /// Rows (pixels).
    pub height: usize,
    /// Distance between neighbouring samples (metres per pixel).
    pub spacing_m: f64,
    /// Heights (metres), `width × height`, index `row * width + col`.
    pub data: Vec<f32>,
}

/// Why a heightfield could not be read or written.
#[derive(Debug)]
pub enum DemError {
    /// The file could not be opened, read or written.
    Io(std::io::Error),
    /// The TIFF is corrupt or uses a layout this reader does not support.
    Tiff(String),
    /// The data is not a usable heightfield (the message says why).
    Invalid(String),
}

impl std::fmt::Display for DemError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DemError::Io(e) => write!(f, "I/O error: {e}"),
            DemError::Tiff(e) => write!(f, "unreadable TIFF: {e}"),
            DemError::Invalid(e) => write!(f, "not a usable heightfield: {e}"),
        }
    }
}

impl std::error::Error for DemError {}

impl From<std::io::Error> for DemError {
    fn from(e: std::io::Error) -> Self {
        DemError::Io(e)
    }
}

impl From<tiff::TiffError> for DemError {
    fn from(e: tiff::TiffError) -> Self {
        DemError::Tiff(e.to_string())
    }
}

/// GeoTIFF's ModelPixelScaleTag: (x, y, z) size of a pixel in model units (metres here).
const MODEL_PIXEL_SCALE: u16 = 33550;

impl Heightfield {
    /// A heightfield of `width × height` samples `spacing_m` metres apart.
    ///
    /// # Panics
    /// If `data.len() != width * height`.
    pub fn new(width: usize, height: usize, spacing_m: f64, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width * height, "heightfield data must hold width × height samples");
        Self { width, height, spacing_m, data }
    }

    /// Height (metres) at column `x`, row `y`.
    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Writes a single-band float32 TIFF (metres) with the pixel size in GeoTIFF's
    /// ModelPixelScaleTag.
    pub fn write_tiff<W: Write + Seek>(&self, out: W) -> Result<(), DemError> {
        let mut enc = TiffEncoder::new(out)?;
        let mut image = enc.new_image::<colortype::Gray32Float>(self.width as u32, self.height as u32)?;
        image
            .encoder()
            .write_tag(Tag::Unknown(MODEL_PIXEL_SCALE), &[self.spacing_m, self.spacing_m, 0.0][..])?;
        image.write_data(&self.data)?;
        Ok(())
    }

    /// Reads a single-band TIFF of heights in metres (float32/64, or 8/16/32-bit integers).
    /// The spacing comes from ModelPixelScaleTag when present, else `default_spacing_m`.
    pub fn read_tiff<R: Read + Seek>(input: R, default_spacing_m: f64) -> Result<Self, DemError> {
        let mut dec = Decoder::new(input)?;
        let (w, h) = dec.dimensions()?;
        if w == 0 || h == 0 || (w as u64) * (h as u64) > 1 << 30 {
            return Err(DemError::Invalid(format!("absurd size {w}×{h}")));
        }
        let spacing = match dec.get_tag_f64_vec(Tag::Unknown(MODEL_PIXEL_SCALE)) {
            Ok(v) if !v.is_empty() && v[0].is_finite() && v[0] > 0.0 => v[0],
            _ => default_spacing_m,
        };
        let data: Vec<f32> = match dec.read_image()? {
            DecodingResult::F32(v) => v,
            DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
            DecodingResult::I16(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::U16(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::I32(v) => v.into_iter().map(|x| x as f32).collect(),
            DecodingResult::U8(v) => v.into_iter().map(f32::from).collect(),
            _ => return Err(DemError::Invalid("unsupported sample type".into())),
        };
        if data.len() != (w as usize) * (h as usize) {
            return Err(DemError::Invalid(format!("{} samples for a {w}×{h} image: multi-band TIFFs are not heightfields", data.len())));
        }
        Ok(Heightfield::new(w as usize, h as usize, spacing, data))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    #[test]
    fn tiff_round_trip_keeps_every_bit_and_the_spacing() {
        let mut data: Vec<f32> = (0..20).map(|k| k as f32 * 13.25 - 40.0).collect();
        data[7] = f32::NAN;
        let hf = Heightfield::new(5, 4, 32.0, data);
        let mut buf = Cursor::new(Vec::new());
        hf.write_tiff(&mut buf).unwrap();
        buf.set_position(0);
        let back = Heightfield::read_tiff(buf, 1.0).unwrap();
        assert_eq!((back.width, back.height, back.spacing_m), (5, 4, 32.0));
        assert!(hf.data.iter().zip(&back.data).all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    #[test]
    fn corrupt_tiff_is_a_clear_error() {
        let err = Heightfield::read_tiff(Cursor::new(b"II*\0garbage".to_vec()), 1.0).unwrap_err();
        assert!(matches!(err, DemError::Tiff(_)), "{err}");
        let err = Heightfield::read_tiff(Cursor::new(Vec::new()), 1.0).unwrap_err();
        assert!(!err.to_string().is_empty());
    }
}
