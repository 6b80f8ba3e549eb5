//! Heightfields: a grid of heights in metres with its sample spacing; readers for the formats
//! users have (GeoTIFF/TIFF, 16-bit PNG heightmaps, Mapbox terrain-RGB PNG), a TIFF writer, and
//! the resampling the resolution ladder needs (area averaging down, bicubic ×2 up).

use std::io::{BufRead, Read, Seek, Write};
use std::path::Path;

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
    /// The file is corrupt or uses a layout this reader does not support.
    Format(String),
    /// The data is not a usable heightfield (the message says why).
    Invalid(String),
}

impl std::fmt::Display for DemError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DemError::Io(e) => write!(f, "I/O error: {e}"),
            DemError::Format(e) => write!(f, "unreadable file: {e}"),
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
        DemError::Format(format!("TIFF: {e}"))
    }
}

impl From<png::DecodingError> for DemError {
    fn from(e: png::DecodingError) -> Self {
        DemError::Format(format!("PNG: {e}"))
    }
}

/// GeoTIFF's ModelPixelScaleTag: (x, y, z) size of a pixel in model units (metres here).
const MODEL_PIXEL_SCALE: u16 = 33550;
/// GDAL's no-data tag: the value (as ASCII) that marks missing samples.
const GDAL_NODATA: u16 = 42113;
/// Heights beyond this magnitude (metres) are not terrain on Earth: the file is not in metres.
const ABSURD_M: f32 = 12_000.0;
/// Largest heightfield read (samples).
const MAX_SAMPLES: u64 = 1 << 28;

/// How grey PNG values map to metres: `height = value × metres_per_unit + offset_m`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PngScale {
    /// Metres per PNG unit.
    pub metres_per_unit: f64,
    /// Height of value 0 (metres).
    pub offset_m: f64,
}

impl Default for PngScale {
    fn default() -> Self {
        Self { metres_per_unit: 1.0, offset_m: 0.0 }
    }
}

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

    /// Fraction of samples that hold data (not NaN).
    pub fn valid_fraction(&self) -> f64 {
        self.data.iter().filter(|v| !v.is_nan()).count() as f64 / self.data.len().max(1) as f64
    }

    /// Checks that the grid holds data and that every height is plausible terrain in metres.
    pub fn validate(self) -> Result<Self, DemError> {
        if self.width == 0 || self.height == 0 {
            return Err(DemError::Invalid("empty grid".into()));
        }
        if !(self.spacing_m.is_finite() && self.spacing_m > 0.0) {
            return Err(DemError::Invalid(format!("spacing {} m is not a positive number", self.spacing_m)));
        }
        let mut any = false;
        for &v in &self.data {
            if v.is_nan() {
                continue;
            }
            if !v.is_finite() || v.abs() > ABSURD_M {
                return Err(DemError::Invalid(format!("height {v} is not terrain in metres (beyond ±{ABSURD_M} m)")));
            }
            any = true;
        }
        if !any {
            return Err(DemError::Invalid("every sample is no-data".into()));
        }
        Ok(self)
    }

    /// Reads a heightfield file by its extension: `.tif`/`.tiff`, or `.png` (16/8-bit grey
    /// scaled by `png_scale`, or 8-bit RGB(A) as terrain-RGB). `spacing_m` overrides the file's
    /// pixel size; one of the two must be known.
    pub fn read_path(path: &Path, spacing_m: Option<f64>, png_scale: PngScale) -> Result<Self, DemError> {
        let bytes = std::fs::read(path)?;
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        let mut hf = match ext.as_str() {
            "tif" | "tiff" => Self::read_tiff(std::io::Cursor::new(bytes), spacing_m.unwrap_or(f64::NAN))?,
            "png" => Self::read_png(std::io::Cursor::new(bytes), png_scale, spacing_m.unwrap_or(f64::NAN))?,
            other => return Err(DemError::Format(format!("unknown extension '.{other}' (expected .tif, .tiff or .png)"))),
        };
        if let Some(s) = spacing_m {
            hf.spacing_m = s;
        }
        if hf.spacing_m.is_nan() {
            return Err(DemError::Invalid(format!("{} has no pixel size: give the spacing in metres", path.display())));
        }
        hf.validate()
    }

    /// Writes a single-band float32 TIFF (metres) with the pixel size in GeoTIFF's
    /// ModelPixelScaleTag and NaN as no-data.
    pub fn write_tiff<W: Write + Seek>(&self, out: W) -> Result<(), DemError> {
        let mut enc = TiffEncoder::new(out)?;
        let mut image = enc.new_image::<colortype::Gray32Float>(self.width as u32, self.height as u32)?;
        image.encoder().write_tag(Tag::Unknown(MODEL_PIXEL_SCALE), &[self.spacing_m, self.spacing_m, 0.0][..])?;
        image.encoder().write_tag(Tag::Unknown(GDAL_NODATA), "nan")?;
        image.write_data(&self.data)?;
        Ok(())
    }

    /// Reads a single-band TIFF of heights in metres (float32/64 or 8/16/32-bit integers).
    /// Samples equal to GDAL's no-data value become NaN. The spacing comes from
    /// ModelPixelScaleTag when present, else `default_spacing_m`. The data is not validated
    /// (see [`Heightfield::validate`]).
    pub fn read_tiff<R: Read + Seek>(input: R, default_spacing_m: f64) -> Result<Self, DemError> {
        let mut dec = Decoder::new(input)?;
        let (w, h) = dec.dimensions()?;
        if w == 0 || h == 0 || (w as u64) * (h as u64) > MAX_SAMPLES {
            return Err(DemError::Invalid(format!("absurd size {w}×{h}")));
        }
        let spacing = match dec.get_tag_f64_vec(Tag::Unknown(MODEL_PIXEL_SCALE)) {
            Ok(v) if !v.is_empty() && v[0].is_finite() && v[0] > 0.0 => v[0],
            _ => default_spacing_m,
        };
        let nodata: Option<f64> = dec.get_tag_ascii_string(Tag::Unknown(GDAL_NODATA)).ok().and_then(|s| s.trim_matches(|c: char| c.is_whitespace() || c == '\0').parse().ok());
        let mut data: Vec<f32> = match dec.read_image()? {
            DecodingResult::F32(v) => v,
            DecodingResult::F64(v) => v.into_iter().map(|x| x as f32).collect(),
            DecodingResult::I16(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::U16(v) => v.into_iter().map(f32::from).collect(),
            DecodingResult::I32(v) => v.into_iter().map(|x| x as f32).collect(),
            DecodingResult::U8(v) => v.into_iter().map(f32::from).collect(),
            _ => return Err(DemError::Format("unsupported TIFF sample type".into())),
        };
        if data.len() != (w as usize) * (h as usize) {
            return Err(DemError::Invalid(format!("{} samples for a {w}×{h} image: multi-band TIFFs are not heightfields", data.len())));
        }
        if let Some(nd) = nodata.filter(|v| !v.is_nan()) {
            let nd = nd as f32;
            data.iter_mut().filter(|v| **v == nd).for_each(|v| *v = f32::NAN);
        }
        Ok(Heightfield::new(w as usize, h as usize, spacing, data))
    }

    /// Reads a PNG heightmap: 16- or 8-bit grey (`height = value × scale + offset`), or 8-bit
    /// RGB/RGBA as Mapbox terrain-RGB (`height = −10000 + (R·65536 + G·256 + B) × 0.1`;
    /// fully transparent pixels are no-data). Not validated.
    pub fn read_png<R: BufRead + Seek>(input: R, scale: PngScale, spacing_m: f64) -> Result<Self, DemError> {
        let mut reader = png::Decoder::new(input).read_info()?;
        let size = reader.output_buffer_size().ok_or_else(|| DemError::Invalid("PNG too large".into()))?;
        let (w, h) = (reader.info().width as usize, reader.info().height as usize);
        if (w as u64) * (h as u64) > MAX_SAMPLES {
            return Err(DemError::Invalid(format!("absurd size {w}×{h}")));
        }
        let mut buf = vec![0u8; size];
        let frame = reader.next_frame(&mut buf)?;
        let line = frame.line_size;
        let mut data = Vec::with_capacity(w * h);
        use png::{BitDepth, ColorType};
        let grey = |v: f64| (v * scale.metres_per_unit + scale.offset_m) as f32;
        for y in 0..h {
            let row = &buf[y * line..(y + 1) * line];
            match (frame.color_type, frame.bit_depth) {
                (ColorType::Grayscale, BitDepth::Sixteen) => data.extend(row.chunks_exact(2).take(w).map(|p| grey(u16::from_be_bytes([p[0], p[1]]) as f64))),
                (ColorType::Grayscale, BitDepth::Eight) => data.extend(row.iter().take(w).map(|&p| grey(p as f64))),
                (ColorType::Rgb | ColorType::Rgba, BitDepth::Eight) => {
                    let n = if frame.color_type == ColorType::Rgb { 3 } else { 4 };
                    data.extend(row.chunks_exact(n).take(w).map(|p| {
                        if n == 4 && p[3] == 0 {
                            f32::NAN
                        } else {
                            (-10_000.0 + ((p[0] as u32) << 16 | (p[1] as u32) << 8 | p[2] as u32) as f64 * 0.1) as f32
                        }
                    }))
                }
                (c, d) => return Err(DemError::Format(format!("PNG of {c:?} at {d:?} is not a heightmap (expected 16/8-bit grey or 8-bit RGB terrain-RGB)"))),
            }
        }
        Ok(Heightfield::new(w, h, spacing_m, data))
    }

    /// The `w × h` window whose top-left sample is (x0, y0).
    pub fn window(&self, x0: usize, y0: usize, w: usize, h: usize) -> Heightfield {
        let mut data = Vec::with_capacity(w * h);
        for y in y0..y0 + h {
            data.extend_from_slice(&self.data[y * self.width + x0..y * self.width + x0 + w]);
        }
        Heightfield::new(w, h, self.spacing_m, data)
    }

    /// Halves the resolution by 2×2 box means (spacing doubles); a mean touching no-data is
    /// no-data. Odd last rows/columns are dropped.
    pub fn downsample2(&self) -> Heightfield {
        let (w, h) = (self.width / 2, self.height / 2);
        let mut data = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let s = self.at(2 * x, 2 * y) + self.at(2 * x + 1, 2 * y) + self.at(2 * x, 2 * y + 1) + self.at(2 * x + 1, 2 * y + 1);
                data.push(s * 0.25);
            }
        }
        Heightfield::new(w, h, self.spacing_m * 2.0, data)
    }

    /// Resamples to a coarser `spacing_m` by area weighting: each output sample is the mean of
    /// the input area it covers (partial pixels weighted by overlap). Never upsamples: a finer
    /// spacing than the input's is an error.
    pub fn resample_area(&self, spacing_m: f64) -> Result<Heightfield, DemError> {
        let f = spacing_m / self.spacing_m;
        if !(f.is_finite() && f >= 1.0 - 1e-9) {
            return Err(DemError::Invalid(format!("cannot resample {} m data to a finer {spacing_m} m", self.spacing_m)));
        }
        let (w, h) = ((self.width as f64 / f).floor() as usize, (self.height as f64 / f).floor() as usize);
        // Separable box: weights of input samples for each output sample along one axis.
        let weights = |n_out: usize| -> Vec<Vec<(usize, f64)>> {
            (0..n_out)
                .map(|o| {
                    let (a, b) = (o as f64 * f, (o + 1) as f64 * f);
                    let mut ws = Vec::new();
                    let mut i = a.floor() as usize;
                    while (i as f64) < b - 1e-9 {
                        let overlap = (b.min(i as f64 + 1.0) - a.max(i as f64)).max(0.0);
                        if overlap > 1e-9 {
                            ws.push((i, overlap / f));
                        }
                        i += 1;
                    }
                    ws
                })
                .collect()
        };
        let (wx, wy) = (weights(w), weights(h));
        let mut rows = vec![0f64; w * self.height];
        for y in 0..self.height {
            for (x, ws) in wx.iter().enumerate() {
                rows[y * w + x] = ws.iter().map(|&(i, wt)| self.at(i, y) as f64 * wt).sum();
            }
        }
        let mut data = Vec::with_capacity(w * h);
        for ws in &wy {
            for x in 0..w {
                data.push(ws.iter().map(|&(j, wt)| rows[j * w + x] * wt).sum::<f64>() as f32);
            }
        }
        Ok(Heightfield::new(w, h, spacing_m, data))
    }

    /// Doubles the resolution by bicubic interpolation (Keys, a = −0.75; sample centres as in
    /// area averaging, so `downsample2` of the result is close to the input; edges clamp).
    pub fn upsample_bicubic2(&self) -> Heightfield {
        self.upsample_bicubic(2)
    }

    /// Multiplies the resolution by `factor` (≥ 1) with bicubic interpolation (Keys,
    /// a = −0.75, pixel-area centres like PyTorch's `align_corners = false`; edges clamp): the
    /// baseline the TEM is measured against.
    pub fn upsample_bicubic(&self, factor: usize) -> Heightfield {
        let f = factor.max(1);
        let (w, h) = (self.width * f, self.height * f);
        let taps = |o: usize, n: usize| -> [(usize, f32); 4] {
            let src = (o as f64 + 0.5) / f as f64 - 0.5;
            let i0 = src.floor();
            let t = (src - i0) as f32;
            let k = cubic_weights(t);
            let mut out = [(0usize, 0f32); 4];
            for (m, slot) in out.iter_mut().enumerate() {
                let i = (i0 as i64 - 1 + m as i64).clamp(0, n as i64 - 1) as usize;
                *slot = (i, k[m]);
            }
            out
        };
        let tx: Vec<_> = (0..w).map(|o| taps(o, self.width)).collect();
        let ty: Vec<_> = (0..h).map(|o| taps(o, self.height)).collect();
        let mut rows = vec![0f32; w * self.height];
        for y in 0..self.height {
            for (x, t) in tx.iter().enumerate() {
                rows[y * w + x] = t.iter().map(|&(i, k)| self.at(i, y) * k).sum();
            }
        }
        let mut data = Vec::with_capacity(w * h);
        for t in &ty {
            for x in 0..w {
                data.push(t.iter().map(|&(j, k)| rows[j * w + x] * k).sum());
            }
        }
        Heightfield::new(w, h, self.spacing_m / f as f64, data)
    }

    /// Replaces no-data (NaN) samples by the nearest valid sample (breadth-first, 4-neighbour
    /// distance). `None` if there is no valid sample at all.
    pub fn fill_nodata(&self) -> Option<Heightfield> {
        let mut data = self.data.clone();
        let mut queue: std::collections::VecDeque<usize> = (0..data.len()).filter(|&i| !data[i].is_nan()).collect();
        if queue.is_empty() {
            return None;
        }
        while let Some(i) = queue.pop_front() {
            let (x, y) = (i % self.width, i / self.width);
            let v = data[i];
            let mut visit = |j: usize| {
                if data[j].is_nan() {
                    data[j] = v;
                    queue.push_back(j);
                }
            };
            if x > 0 {
                visit(i - 1);
            }
            if x + 1 < self.width {
                visit(i + 1);
            }
            if y > 0 {
                visit(i - self.width);
            }
            if y + 1 < self.height {
                visit(i + self.width);
            }
        }
        Some(Heightfield::new(self.width, self.height, self.spacing_m, data))
    }
}

/// Keys cubic convolution weights (a = −0.75) for the 4 taps around fractional offset `t`.
pub fn cubic_weights(t: f32) -> [f32; 4] {
    let a = -0.75f32;
    let near = |x: f32| ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0;
    let far = |x: f32| ((a * x - 5.0 * a) * x + 8.0 * a) * x - 4.0 * a;
    [far(t + 1.0), near(t), near(1.0 - t), far(2.0 - t)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    /// The shared data folder beside the repository (CI clones the repo with shared/ beside it).
    fn shared(rel: &str) -> std::path::PathBuf {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("shared").join(rel);
        assert!(p.exists(), "missing {}: the tests read ../shared", p.display());
        p
    }

    #[test]
    fn tiff_round_trip_keeps_every_bit_the_spacing_and_no_data() {
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
    fn int16_tiff_with_a_nodata_value_reads_as_metres_and_nan() {
        let mut buf = Cursor::new(Vec::new());
        {
            let mut enc = TiffEncoder::new(&mut buf).unwrap();
            let mut img = enc.new_image::<colortype::GrayI16>(3, 2).unwrap();
            img.encoder().write_tag(Tag::Unknown(GDAL_NODATA), "-32768").unwrap();
            img.write_data(&[100i16, -32768, 2500, -5, 0, 7]).unwrap();
        }
        buf.set_position(0);
        let hf = Heightfield::read_tiff(buf, 30.0).unwrap().validate().unwrap();
        assert_eq!(hf.spacing_m, 30.0);
        assert_eq!(hf.at(0, 0), 100.0);
        assert!(hf.at(1, 0).is_nan());
        assert_eq!(hf.at(0, 1), -5.0);
        assert!((hf.valid_fraction() - 5.0 / 6.0).abs() < 1e-9);
    }

    #[test]
    fn shared_dems_read_with_their_spacing() {
        let hf = Heightfield::read_path(&shared("dem/pypi_lidar_dem_1m.tif"), Some(1.0), PngScale::default()).unwrap();
        assert_eq!((hf.width, hf.height), (400, 400));
        let chiri = Heightfield::read_path(&shared("dem/landlab_chiri_1m.tif"), Some(1.0), PngScale::default()).unwrap();
        assert!((chiri.valid_fraction() - 0.469).abs() < 0.01, "{}", chiri.valid_fraction());
    }

    #[test]
    fn terrain_rgb_fixture_decodes_to_plausible_heights() {
        let hf = Heightfield::read_path(&shared("fixtures/fuji_terrain_rgb.png"), Some(30.0), PngScale::default()).unwrap();
        let max = hf.data.iter().copied().filter(|v| !v.is_nan()).fold(f32::MIN, f32::max);
        let min = hf.data.iter().copied().filter(|v| !v.is_nan()).fold(f32::MAX, f32::min);
        assert!((2500.0..4000.0).contains(&max), "Fuji's summit is 3776 m, read {max}");
        assert!(min < 1500.0, "the foot is far lower: {min}");
    }

    #[test]
    fn png16_heightmaps_apply_the_scale() {
        let mut bytes = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut bytes, 2, 1);
            enc.set_color(png::ColorType::Grayscale);
            enc.set_depth(png::BitDepth::Sixteen);
            let mut wr = enc.write_header().unwrap();
            wr.write_image_data(&[0x01, 0x00, 0xFF, 0xFF]).unwrap();
        }
        let hf = Heightfield::read_png(Cursor::new(bytes), PngScale { metres_per_unit: 0.1, offset_m: -100.0 }, 5.0).unwrap();
        assert_eq!(hf.data, vec![256.0 * 0.1 - 100.0, 65535.0 * 0.1 - 100.0]);
    }

    #[test]
    fn corrupt_or_absurd_files_are_clear_errors() {
        let err = Heightfield::read_tiff(Cursor::new(b"II*\0garbage".to_vec()), 1.0).unwrap_err();
        assert!(matches!(err, DemError::Format(_)), "{err}");
        assert!(Heightfield::read_png(Cursor::new(b"\x89PNG\r\n\x1a\nxx".to_vec()), PngScale::default(), 1.0).is_err());
        let absurd = Heightfield::new(2, 1, 1.0, vec![0.0, 1.0e6]).validate().unwrap_err();
        assert!(absurd.to_string().contains("not terrain"), "{absurd}");
        let empty = Heightfield::new(1, 1, 1.0, vec![f32::NAN]).validate().unwrap_err();
        assert!(empty.to_string().contains("no-data"));
        let p = std::env::temp_dir().join("terrain-not-a-dem.xyz");
        std::fs::write(&p, b"x").unwrap();
        assert!(Heightfield::read_path(&p, Some(1.0), PngScale::default()).unwrap_err().to_string().contains("extension"));
    }

    #[test]
    fn area_resampling_preserves_means_and_refuses_to_upsample() {
        let hf = Heightfield::new(4, 4, 1.0, (0..16).map(|k| k as f32).collect());
        let d = hf.downsample2();
        assert_eq!(d.data, vec![2.5, 4.5, 10.5, 12.5]);
        assert_eq!(d.spacing_m, 2.0);
        let r = hf.resample_area(2.0).unwrap();
        assert_eq!(r.data, d.data);
        let big = Heightfield::new(10, 10, 20.0, (0..100).map(|k| (k % 10) as f32 * 3.0).collect());
        let r = big.resample_area(32.0).unwrap();
        assert_eq!((r.width, r.height), (6, 6));
        // A linear ramp stays a ramp: the first output covers input x ∈ [0, 1.6) → mean x 0.8·… .
        let expected0 = (1.0 * 0.0 + 0.6 * 3.0) / 1.6;
        assert!((r.at(0, 0) as f64 - expected0).abs() < 1e-4, "{}", r.at(0, 0));
        assert!(big.resample_area(10.0).is_err());
        let nan = Heightfield::new(2, 2, 1.0, vec![1.0, f32::NAN, 1.0, 1.0]).downsample2();
        assert!(nan.data[0].is_nan());
    }

    #[test]
    fn bicubic_upsampling_follows_smooth_surfaces() {
        // Keys' kernel with a = −0.75 (as PyTorch's bicubic) keeps constants exactly and
        // follows a ramp to within 5 % of its slope per coarse sample.
        let hf = Heightfield::new(8, 8, 2.0, (0..64).map(|k| (k % 8) as f32 * 4.0 + (k / 8) as f32).collect());
        let up = hf.upsample_bicubic2();
        assert_eq!((up.width, up.height, up.spacing_m), (16, 16, 1.0));
        for y in 4..12 {
            for x in 4..12 {
                let want = (x as f32 * 0.5 - 0.25) * 4.0 + (y as f32 * 0.5 - 0.25);
                assert!((up.at(x, y) - want).abs() < 0.05 * 5.0, "({x},{y}) {} vs {want}", up.at(x, y));
            }
        }
        let flat = Heightfield::new(4, 4, 1.0, vec![123.5; 16]).upsample_bicubic2();
        assert!(flat.data.iter().all(|&v| (v - 123.5).abs() < 1e-4));
        let w: f32 = cubic_weights(0.3).iter().sum();
        assert!((w - 1.0).abs() < 1e-6);
    }
}
