//! Heightmap PNGs the user opened to pin: a PNG says neither its spacing nor (grey) what its
//! values are in metres, so the page asks before pinning it. A JSON sidecar of this project's
//! own exports (`NAME.png.json`: spacing, the metres of 0 and 65535) dropped with it fills the
//! answers in. Mapbox terrain-RGB PNGs state their heights; only their spacing is asked.

use crate::dem::{Heightfield, PngScale};

/// What a heightmap PNG's values mean.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PngKind {
    /// Grey, 16- or 8-bit: values 0 ..= `max_value` between two heights the user states.
    Grey {
        /// The largest value (65535 or 255).
        max_value: u32,
    },
    /// 8-bit RGB(A) Mapbox terrain-RGB: −10000 m + (R·65536 + G·256 + B) × 0.1 m.
    TerrainRgb,
}

/// A heightmap PNG waiting for its spacing and heights.
#[derive(Clone, Debug, PartialEq)]
pub struct PendingPng {
    /// The file's name.
    pub name: String,
    bytes: Vec<u8>,
    /// What its values mean.
    pub kind: PngKind,
    /// Samples per row and rows.
    pub size: (usize, usize),
    /// Metres between neighbouring samples (asked).
    pub spacing_m: f64,
    /// Height (metres) of value 0 (grey; asked).
    pub low_m: f64,
    /// Height (metres) of the largest value (grey; asked).
    pub high_m: f64,
    /// The answers came from a sidecar (its name).
    pub sidecar: Option<String>,
}

impl PendingPng {
    /// The PNG in `bytes` (named `name`) as a heightmap waiting for its scale, with answers to
    /// start from (32 m; grey 0 to 1,000 m), or why it is not a heightmap PNG. Only its header
    /// is read here.
    pub fn new(name: &str, bytes: Vec<u8>) -> Result<Self, String> {
        use png::{BitDepth, ColorType};
        let (colour, depth, width, height) = {
            let reader = png::Decoder::new(std::io::Cursor::new(&bytes)).read_info().map_err(|e| format!("{name}: {e}"))?;
            let info = reader.info();
            (info.color_type, info.bit_depth, info.width as usize, info.height as usize)
        };
        let kind = match (colour, depth) {
            (ColorType::Grayscale, BitDepth::Sixteen) => PngKind::Grey { max_value: 65535 },
            (ColorType::Grayscale, BitDepth::Eight) => PngKind::Grey { max_value: 255 },
            (ColorType::Rgb | ColorType::Rgba, BitDepth::Eight) => PngKind::TerrainRgb,
            (c, d) => return Err(format!("{name} is a PNG of {c:?} at {d:?}: a heightmap is 16- or 8-bit grey, or 8-bit RGB terrain-RGB")),
        };
        Ok(Self { name: name.into(), bytes, kind, size: (width, height), spacing_m: 32.0, low_m: 0.0, high_m: 1000.0, sidecar: None })
    }

    /// Takes the answers from `json` (a sidecar named `sidecar_name`: `file`, `spacing_m`,
    /// `min_m`, `max_m`) when it describes this file. Returns whether it did.
    pub fn apply_sidecar(&mut self, sidecar_name: &str, json: &serde_json::Value) -> bool {
        let num = |k: &str| json.get(k).and_then(serde_json::Value::as_f64).filter(|v| v.is_finite());
        let describes = json.get("file").and_then(serde_json::Value::as_str) == Some(self.name.as_str()) || sidecar_name == format!("{}.json", self.name);
        let (Some(spacing), Some(low), Some(high)) = (num("spacing_m"), num("min_m"), num("max_m")) else { return false };
        if !describes || spacing <= 0.0 {
            return false;
        }
        (self.spacing_m, self.low_m, self.high_m, self.sidecar) = (spacing, low, high, Some(sidecar_name.into()));
        true
    }

    /// The heightmap in metres with the answers given, or why it cannot be read.
    pub fn heightfield(&self) -> Result<Heightfield, String> {
        if !(self.spacing_m.is_finite() && self.spacing_m > 0.0) {
            return Err(format!("{}: the spacing must be a positive number of metres, not {}", self.name, self.spacing_m));
        }
        let scale = match self.kind {
            PngKind::Grey { max_value } => PngScale { metres_per_unit: (self.high_m - self.low_m) / max_value as f64, offset_m: self.low_m },
            PngKind::TerrainRgb => PngScale::default(),
        };
        Heightfield::read_png(std::io::Cursor::new(&self.bytes), scale, self.spacing_m).map_err(|e| format!("{}: {e}", self.name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(width: u32, colour: png::ColorType, depth: png::BitDepth, data: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        let mut e = png::Encoder::new(&mut out, width, 1);
        e.set_color(colour);
        e.set_depth(depth);
        e.write_header().unwrap().write_image_data(data).unwrap();
        out
    }

    /// A 16-bit grey PNG gives value × (high − low) / 65535 + low metres at the asked spacing,
    /// its sidecar (by its `file`) fills the answers in and another file's does not; terrain-RGB
    /// gives −10000 + code × 0.1 m; an RGB PNG of 16 bits and a spacing of 0 are refused.
    #[test]
    fn heightmap_pngs_are_read_with_the_answers_given_or_their_sidecars() {
        let grey = png(2, png::ColorType::Grayscale, png::BitDepth::Sixteen, &[0, 0, 255, 255]);
        let mut p = PendingPng::new("h.png", grey).unwrap();
        assert_eq!((p.kind, p.size), (PngKind::Grey { max_value: 65535 }, (2, 1)));
        (p.spacing_m, p.low_m, p.high_m) = (8.0, 100.0, 1100.0);
        let hf = p.heightfield().unwrap();
        assert_eq!((hf.spacing_m, hf.data.clone()), (8.0, vec![100.0, 1100.0]));
        assert!(!p.apply_sidecar("other.png.json", &serde_json::json!({"file": "other.png", "spacing_m": 2.0, "min_m": 0.0, "max_m": 1.0})));
        assert!(p.apply_sidecar("x.json", &serde_json::json!({"file": "h.png", "spacing_m": 32.0, "min_m": -5.0, "max_m": 2000.0})));
        assert_eq!(p.heightfield().unwrap().data, vec![-5.0, 2000.0]);
        assert_eq!(p.sidecar.as_deref(), Some("x.json"));
        // 1 × 0.1 m above −10000: code 100000 = 0x0186A0.
        let rgb = png(1, png::ColorType::Rgb, png::BitDepth::Eight, &[0x01, 0x86, 0xA0]);
        let t = PendingPng::new("t.png", rgb).unwrap();
        assert_eq!(t.kind, PngKind::TerrainRgb);
        assert_eq!(t.heightfield().unwrap().data, vec![0.0]);
        let deep = png(1, png::ColorType::Rgb, png::BitDepth::Sixteen, &[0; 6]);
        assert!(PendingPng::new("d.png", deep).unwrap_err().contains("is a PNG of Rgb at Sixteen"));
        p.spacing_m = 0.0;
        assert!(p.heightfield().unwrap_err().contains("the spacing must be a positive number"));
    }
}
