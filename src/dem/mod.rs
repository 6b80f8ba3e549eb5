//! Heightfields: a grid of heights in metres with its sample spacing; readers for the formats
//! users have (GeoTIFF/TIFF, 16-bit PNG heightmaps, Mapbox terrain-RGB PNG), a TIFF writer, and
//! the resampling the resolution ladder needs (area averaging down, bicubic ×2 up).

pub mod formats;
mod shade;

use std::io::{BufRead, Read, Seek, SeekFrom, Write};
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
    /// Where the grid lies on Earth, when the file said so (GeoTIFF).
    pub geo: Option<GeoRef>,
}

/// A grid's place in a projected coordinate system (GeoTIFF's tiepoint and CRS keys).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeoRef {
    /// Model coordinates (metres: x east, y north) of the outer north-west corner of sample
    /// (0, 0).
    pub origin_m: [f64; 2],
    /// EPSG code of the projected CRS, when known; `None` is a local metric frame (written as
    /// user-defined).
    pub epsg: Option<u16>,
}

/// Why a heightfield could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum DemError {
    /// The file could not be opened, read or written.
    #[error("I/O error: {0}")]
    Io(#[from] std::io::Error),
    /// The file is corrupt or uses a layout this reader does not support.
    #[error("unreadable file: {0}")]
    Format(String),
    /// The data is not a usable heightfield (the message says why).
    #[error("not a usable heightfield: {0}")]
    Invalid(String),
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

/// The end of the error for a file without a pixel size and no spacing given.
const NO_PIXEL_SIZE: &str = " has no pixel size: give the spacing in metres";

/// GeoTIFF's ModelPixelScaleTag: (x, y, z) size of a pixel in model units.
const MODEL_PIXEL_SCALE: u16 = 33550;
/// GeoTIFF's ModelTiepointTag: (i, j, k, x, y, z) raster point (i, j) at model (x, y).
const MODEL_TIEPOINT: u16 = 33922;
/// GeoTIFF's GeoKeyDirectoryTag: header (1, 1, 0, n) then n × (key, location, count, value).
const GEO_KEY_DIRECTORY: u16 = 34735;
/// GeoKeys this crate reads and writes.
mod geokey {
    /// GTModelTypeGeoKey: 1 projected, 2 geographic (degrees), 3 geocentric.
    pub const MODEL_TYPE: u16 = 1024;
    /// GTRasterTypeGeoKey: 1 pixel is area, 2 pixel is point.
    pub const RASTER_TYPE: u16 = 1025;
    /// ProjectedCSTypeGeoKey: EPSG code, 32767 user-defined.
    pub const PROJECTED_CS: u16 = 3072;
    /// ProjLinearUnitsGeoKey: 9001 metre, 9002 foot, 9003 US survey foot.
    pub const LINEAR_UNITS: u16 = 3076;
}
/// GDAL's no-data tag: the value (as ASCII) that marks missing samples.
const GDAL_NODATA: u16 = 42113;
/// Heights beyond this magnitude (metres) are not terrain on Earth: the file is not in metres.
const ABSURD_M: f32 = 12_000.0;
/// Largest heightfield read (samples): 2²⁶, e.g. 8192 × 8192 (256 MiB as f32).
pub const MAX_SAMPLES: u64 = 1 << 26;
/// Largest expansion of compressed image data over its file that a reader believes: deflate
/// peaks near 1032:1. A header that claims more raw bytes than this times the file's size
/// (plus [`SLACK_BYTES`]) is forged or truncated, and is refused before anything is allocated.
const MAX_EXPANSION: u64 = 1100;
/// Bytes any file may expand to regardless of its size (small images, headers).
const SLACK_BYTES: u64 = 1 << 20;
/// Largest pixel spacing read as degrees (a metric grid has spacings far above this).
const MAX_DEGREE_SPACING: f64 = 0.1;
/// Largest difference between the east–west and north–south size of a pixel (as a fraction,
/// in metres for a degree pixel) that is read as a square grid; beyond it the file must be
/// reprojected or resampled first.
const MAX_PIXEL_ANISOTROPY: f64 = 0.02;

/// Checks declared image dimensions before any allocation: at most [`MAX_SAMPLES`] samples,
/// and at most `raw_bytes` that `file_len` bytes can plausibly hold.
fn check_size(w: u64, h: u64, bytes_per_pixel: u64, file_len: u64, what: &str) -> Result<(), DemError> {
    let samples = w.saturating_mul(h);
    if w == 0 || h == 0 {
        return Err(DemError::Invalid(format!("{what} of {w}×{h} samples is empty")));
    }
    if samples > MAX_SAMPLES {
        return Err(DemError::Invalid(format!("{what} of {w}×{h} samples is larger than the {MAX_SAMPLES} samples (8192 × 8192) read at once: crop or downsample it first")));
    }
    let raw = samples.saturating_mul(bytes_per_pixel.max(1));
    if raw > file_len.saturating_mul(MAX_EXPANSION).saturating_add(SLACK_BYTES) {
        return Err(DemError::Format(format!("{what} claims {w}×{h} samples ({raw} bytes) but the file has {file_len} bytes: it is truncated or its header is wrong")));
    }
    Ok(())
}

/// Length of a seekable stream; the position is back at the start afterwards.
fn stream_len<S: Seek>(s: &mut S) -> Result<u64, DemError> {
    let n = s.seek(SeekFrom::End(0))?;
    s.seek(SeekFrom::Start(0))?;
    Ok(n)
}

/// Metres per degree of longitude and of latitude at latitude `lat_deg` (WGS 84).
pub fn metres_per_degree(lat_deg: f64) -> (f64, f64) {
    let p = lat_deg.to_radians();
    let lon = 111_412.84 * p.cos() - 93.5 * (3.0 * p).cos() + 0.118 * (5.0 * p).cos();
    let lat = 111_132.92 - 559.82 * (2.0 * p).cos() + 1.175 * (4.0 * p).cos() - 0.0023 * (6.0 * p).cos();
    (lon, lat)
}

/// Value of GeoKey `key` in a GeoKeyDirectory (only keys stored inline, as all read here are).
fn geo_key(dir: &[u16], key: u16) -> Option<u16> {
    dir.get(4..)?.chunks_exact(4).find(|e| e[0] == key && e[1] == 0).map(|e| e[3])
}

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
        Self { width, height, spacing_m, data, geo: None }
    }

    /// The same grid placed at `geo`.
    pub fn with_geo(mut self, geo: Option<GeoRef>) -> Self {
        self.geo = geo;
        self
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
        let mut hf = Self::read_unchecked(path, png_scale)?;
        if let Some(s) = spacing_m {
            hf.spacing_m = s;
        }
        if hf.spacing_m.is_nan() {
            return Err(DemError::Invalid(format!("{}{NO_PIXEL_SIZE}", path.display())));
        }
        hf.validate()
    }

    /// Reads a DEM a user gave with the spacing they gave, if any: the file's own pixel size
    /// (GeoTIFF) is used when it has one, and a `given` spacing that differs from it by more
    /// than 1 % is refused (the message says both); a file without one (a PNG, a plain TIFF)
    /// needs `given`.
    pub fn read_user_path(path: &Path, given: Option<f64>, png_scale: PngScale) -> Result<Self, DemError> {
        let mut hf = Self::read_unchecked(path, png_scale)?;
        match given {
            Some(g) if hf.spacing_m.is_nan() => hf.spacing_m = g,
            None if hf.spacing_m.is_nan() => return Err(DemError::Invalid(format!("{}{NO_PIXEL_SIZE}", path.display()))),
            Some(g) if (g - hf.spacing_m).abs() > 0.01 * hf.spacing_m => {
                return Err(DemError::Invalid(format!(
                    "{} says its pixels are {} m, but {g} m was given: leave the spacing out to use the file's own, or resample the file",
                    path.display(),
                    hf.spacing_m
                )));
            }
            _ => {}
        }
        hf.validate()
    }

    /// The heightfield in the file at `path`, by its extension, with the file's own pixel size
    /// or NaN where it has none; not validated.
    fn read_unchecked(path: &Path, png_scale: PngScale) -> Result<Self, DemError> {
        let bytes = std::io::Cursor::new(std::fs::read(path)?);
        match path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase().as_str() {
            "tif" | "tiff" => Self::read_tiff(bytes, f64::NAN),
            "png" => Self::read_png(bytes, png_scale, f64::NAN),
            other => Err(DemError::Format(format!("unknown extension '.{other}' (expected .tif, .tiff or .png)"))),
        }
    }

    /// Writes a single-band float32 GeoTIFF (metres, NaN as no-data): the pixel size
    /// (ModelPixelScale), the north-west corner (ModelTiepoint; (0, 0) without a [`GeoRef`])
    /// and GeoKeys for a projected CRS in metres, pixel-is-area, with its EPSG code when known
    /// (else user-defined, a local frame).
    pub fn write_tiff<W: Write + Seek>(&self, out: W) -> Result<(), DemError> {
        let mut enc = TiffEncoder::new(out)?;
        let mut image = enc.new_image::<colortype::Gray32Float>(self.width as u32, self.height as u32)?;
        let geo = self.geo.unwrap_or(GeoRef { origin_m: [0.0, 0.0], epsg: None });
        image.encoder().write_tag(Tag::Unknown(MODEL_PIXEL_SCALE), &[self.spacing_m, self.spacing_m, 0.0][..])?;
        image.encoder().write_tag(Tag::Unknown(MODEL_TIEPOINT), &[0.0, 0.0, 0.0, geo.origin_m[0], geo.origin_m[1], 0.0][..])?;
        let keys: [u16; 20] =
            [1, 1, 0, 4, geokey::MODEL_TYPE, 0, 1, 1, geokey::RASTER_TYPE, 0, 1, 1, geokey::PROJECTED_CS, 0, 1, geo.epsg.unwrap_or(32767), geokey::LINEAR_UNITS, 0, 1, 9001];
        image.encoder().write_tag(Tag::Unknown(GEO_KEY_DIRECTORY), &keys[..])?;
        image.encoder().write_tag(Tag::Unknown(GDAL_NODATA), "nan")?;
        image.write_data(&self.data)?;
        Ok(())
    }

    /// Reads a single-band TIFF of heights in metres (float32/64 or 8/16/32-bit integers).
    /// Samples equal to GDAL's no-data value become NaN. The spacing comes from
    /// ModelPixelScaleTag when present (metres, feet converted; degrees of a geographic CRS
    /// converted at the grid's latitude when the pixels are square within 2 %, refused
    /// otherwise), else `default_spacing_m`. Dimensions are checked against [`MAX_SAMPLES`]
    /// and the file's size before anything is allocated. The data is not validated (see
    /// [`Heightfield::validate`]).
    pub fn read_tiff<R: Read + Seek>(mut input: R, default_spacing_m: f64) -> Result<Self, DemError> {
        let file_len = stream_len(&mut input)?;
        let limits = {
            let mut l = tiff::decoder::Limits::default();
            l.decoding_buffer_size = (MAX_SAMPLES * 8) as usize;
            l
        };
        let mut dec = Decoder::new(input)?.with_limits(limits);
        let (w, h) = dec.dimensions()?;
        let bits: u64 = dec.get_tag_u16_vec(Tag::BitsPerSample).map(|v| v.iter().map(|&b| b as u64).sum()).unwrap_or(8);
        check_size(w as u64, h as u64, bits.div_ceil(8), file_len, "the TIFF")?;
        let scale = dec.get_tag_f64_vec(Tag::Unknown(MODEL_PIXEL_SCALE)).ok().filter(|v| v.len() >= 2 && v[..2].iter().all(|s| s.is_finite() && *s > 0.0));
        let tie = dec.get_tag_f64_vec(Tag::Unknown(MODEL_TIEPOINT)).ok().filter(|v| v.len() >= 6 && v.iter().all(|x| x.is_finite()));
        let keys = dec.get_tag_u16_vec(Tag::Unknown(GEO_KEY_DIRECTORY)).unwrap_or_default();
        let (spacing, geo) = georeference(scale.as_deref(), tie.as_deref(), &keys, h, default_spacing_m)?;
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
        Ok(Heightfield::new(w as usize, h as usize, spacing, data).with_geo(geo))
    }

    /// Reads a PNG heightmap: 16- or 8-bit grey (`height = value × scale + offset`), or 8-bit
    /// RGB/RGBA as Mapbox terrain-RGB (`height = −10000 + (R·65536 + G·256 + B) × 0.1`;
    /// fully transparent pixels are no-data). Not validated.
    /// Dimensions are checked against [`MAX_SAMPLES`] and the file's size before anything is
    /// allocated.
    pub fn read_png<R: BufRead + Seek>(mut input: R, scale: PngScale, spacing_m: f64) -> Result<Self, DemError> {
        let file_len = stream_len(&mut input)?;
        let limits = png::Limits { bytes: (MAX_SAMPLES * 8) as usize };
        let mut reader = png::Decoder::new_with_limits(input, limits).read_info()?;
        let (w, h) = (reader.info().width as usize, reader.info().height as usize);
        let bytes_per_pixel = reader.info().bytes_per_pixel() as u64;
        check_size(w as u64, h as u64, bytes_per_pixel, file_len, "the PNG")?;
        let size = reader.output_buffer_size().ok_or_else(|| DemError::Invalid("PNG too large".into()))?;
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
                    data.extend(
                        row.chunks_exact(n)
                            .take(w)
                            .map(|p| if n == 4 && p[3] == 0 { f32::NAN } else { (-10_000.0 + ((p[0] as u32) << 16 | (p[1] as u32) << 8 | p[2] as u32) as f64 * 0.1) as f32 }),
                    )
                }
                (c, d) => return Err(DemError::Format(format!("PNG of {c:?} at {d:?} is not a heightmap (expected 16/8-bit grey or 8-bit RGB terrain-RGB)"))),
            }
        }
        Ok(Heightfield::new(w, h, spacing_m, data))
    }

    /// The `w × h` window whose top-left sample is (x0, y0), placed where it lies.
    pub fn window(&self, x0: usize, y0: usize, w: usize, h: usize) -> Heightfield {
        let mut data = Vec::with_capacity(w * h);
        for y in y0..y0 + h {
            data.extend_from_slice(&self.data[y * self.width + x0..y * self.width + x0 + w]);
        }
        let s = self.spacing_m;
        let geo = self.geo.map(|g| GeoRef { origin_m: [g.origin_m[0] + x0 as f64 * s, g.origin_m[1] - y0 as f64 * s], ..g });
        Heightfield::new(w, h, s, data).with_geo(geo)
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
        let (w, h) = (self.width, self.height);
        let nan = |i: usize| data[i].is_nan();
        let beside_nodata = |i: usize| {
            let (x, y) = (i % w, i / w);
            (x > 0 && nan(i - 1)) || (x + 1 < w && nan(i + 1)) || (y > 0 && nan(i - w)) || (y + 1 < h && nan(i + w))
        };
        // Only valid samples beside no-data ever fill one; in index order, as the search from
        // every valid sample would meet them (a 4096² DEM without no-data queues nothing).
        let mut queue: std::collections::VecDeque<usize> = (0..data.len()).filter(|&i| !nan(i) && beside_nodata(i)).collect();
        if queue.is_empty() {
            return data.iter().any(|v| !v.is_nan()).then(|| Heightfield::new(w, h, self.spacing_m, data));
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

/// The pixel spacing (metres) and georeference from GeoTIFF tags: `scale` (ModelPixelScale),
/// `tie` (ModelTiepoint), `keys` (GeoKeyDirectory, may be empty) of an image `rows` high.
fn georeference(scale: Option<&[f64]>, tie: Option<&[f64]>, keys: &[u16], rows: u32, default_spacing_m: f64) -> Result<(f64, Option<GeoRef>), DemError> {
    let model = geo_key(keys, geokey::MODEL_TYPE);
    let Some(s) = scale else { return Ok((default_spacing_m, None)) };
    let corner = tie.map(|t| [t[3] - t[0] * s[0], t[4] + t[1] * s[1]]);
    let geographic = model == Some(2) || (model.is_none() && s[0] < MAX_DEGREE_SPACING && corner.is_some_and(|c| c[0].abs() <= 180.0 && c[1].abs() <= 90.0));
    if geographic {
        let Some([_, north]) = corner else {
            return Err(DemError::Invalid(format!("the pixel size {}° is in degrees but the file has no tiepoint to tell its latitude: give the spacing in metres", s[0])));
        };
        let lat = north - 0.5 * rows as f64 * s[1];
        if !(-89.0..=89.0).contains(&lat) {
            return Err(DemError::Invalid(format!("latitude {lat:.2}° is too close to a pole for degree pixels")));
        }
        let (per_lon, per_lat) = metres_per_degree(lat);
        let (sx, sy) = (s[0] * per_lon, s[1] * per_lat);
        if ((sx - sy) / sy).abs() > MAX_PIXEL_ANISOTROPY {
            return Err(DemError::Invalid(format!(
                "the pixels are {sx:.1} m × {sy:.1} m ({}° × {}° at {lat:.1}°): heightfields need square pixels, so reproject the file to a metric CRS (e.g. UTM) first",
                s[0], s[1]
            )));
        }
        return Ok((0.5 * (sx + sy), None));
    }
    let unit_m = match geo_key(keys, geokey::LINEAR_UNITS) {
        None | Some(9001) => 1.0,
        Some(9002) => 0.3048,
        Some(9003) => 1200.0 / 3937.0,
        Some(u) => return Err(DemError::Invalid(format!("linear unit {u} (EPSG) is not supported: metres or feet"))),
    };
    if let [sx, sy, ..] = *s
        && ((sx - sy) / sy).abs() > MAX_PIXEL_ANISOTROPY
    {
        return Err(DemError::Invalid(format!("the pixels are {sx} × {sy} (model units): heightfields need square pixels, so resample the file to square pixels first")));
    }
    let epsg = geo_key(keys, geokey::PROJECTED_CS).filter(|&c| c != 32767 && c != 0);
    let geo = corner.map(|c| GeoRef { origin_m: [c[0] * unit_m, c[1] * unit_m], epsg });
    Ok((s[0] * unit_m, geo))
}

/// Applies dihedral transform `t` (0..8: 4 rotations × optional flip) to a square grid of side
/// `n` (row-major); [`dihedral_inverse`] undoes it.
pub fn dihedral(src: &[f32], n: usize, t: usize) -> Vec<f32> {
    let mut out = vec![0f32; n * n];
    for y in 0..n {
        for x in 0..n {
            let (mut u, mut v) = (x, y);
            if t & 4 != 0 {
                u = n - 1 - u;
            }
            (u, v) = match t & 3 {
                0 => (u, v),
                1 => (n - 1 - v, u),
                2 => (n - 1 - u, n - 1 - v),
                _ => (v, n - 1 - u),
            };
            out[y * n + x] = src[v * n + u];
        }
    }
    out
}

/// [`dihedral`] applied to each `n`² channel of a channel-first stack (`src.len()` a multiple
/// of `n`²).
pub fn dihedral_channels(src: &[f32], n: usize, t: usize) -> Vec<f32> {
    src.chunks_exact(n * n).flat_map(|c| dihedral(c, n, t)).collect()
}

/// The transform that undoes [`dihedral`] transform `t`: quarter turns swap, the half turn and the
/// four mirrorings undo themselves.
pub fn dihedral_inverse(t: usize) -> usize {
    match t {
        1 => 3,
        3 => 1,
        t => t,
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
mod tests;
