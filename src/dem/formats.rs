//! Heightfields out to the formats other tools read: 16-bit PNG and little-endian 16-bit RAW
//! (each with a JSON sidecar that states the metres of 0 and 65535 and the spacing: tools
//! that import heightmaps guess neither), binary glTF (a mesh with normals), and the
//! GeoTIFF of [`Heightfield::write_tiff`]; square 2ⁿ+1 grids on request (Unity and Unreal
//! want them). The format follows the file's extension.

use std::io::{Cursor, Write};
use std::path::Path;

use serde::Serialize;

use super::{DemError, Heightfield};

/// What a 16-bit PNG or RAW export says about itself (written beside it as `NAME.json`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Sidecar {
    /// The file it describes.
    pub file: String,
    /// "png16" (big-endian grey, as PNG stores it) or "raw16le".
    pub format: &'static str,
    /// Samples per row.
    pub width: usize,
    /// Rows (row 0 at the north).
    pub height: usize,
    /// Metres between neighbouring samples.
    pub spacing_m: f64,
    /// Height (metres) of value 0: the lowest sample.
    pub min_m: f64,
    /// Height (metres) of value 65535: the highest sample.
    pub max_m: f64,
    /// Metres per unit: `height = min_m + value × metres_per_unit`.
    pub metres_per_unit: f64,
    /// Samples that had no data (written as 0).
    pub nodata_samples: usize,
}

/// The export formats, by file extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// `.tif` / `.tiff`: float32 GeoTIFF.
    GeoTiff,
    /// `.png`: 16-bit grey PNG + JSON sidecar.
    Png16,
    /// `.raw` / `.r16`: little-endian 16-bit RAW + JSON sidecar.
    Raw16,
    /// `.glb`: binary glTF mesh with normals.
    Glb,
}

impl Format {
    /// The format of `path`'s extension, or an error listing the ones there are.
    pub fn of(path: &Path) -> Result<Self, DemError> {
        match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
            Some("tif" | "tiff") => Ok(Self::GeoTiff),
            Some("png") => Ok(Self::Png16),
            Some("raw" | "r16") => Ok(Self::Raw16),
            Some("glb") => Ok(Self::Glb),
            _ => Err(DemError::Invalid(format!("{}: export to .tif (GeoTIFF), .png (16-bit), .raw (16-bit little-endian) or .glb (mesh)", path.display()))),
        }
    }
}

/// The file's bytes and, for PNG and RAW, its sidecar.
pub struct Exported {
    /// The file's bytes.
    pub bytes: Vec<u8>,
    /// The sidecar (PNG and RAW).
    pub sidecar: Option<Sidecar>,
}

impl Heightfield {
    /// This grid resampled (bilinear, corner-aligned) to a square of `2ⁿ + 1` samples per side,
    /// the smallest such side ≥ its longer side, over the square its longer side spans; the
    /// spacing becomes that span over the side minus one. Missing samples stay missing.
    pub fn to_pow2_plus_1(&self) -> Heightfield {
        let long = self.width.max(self.height).max(2);
        let side = (long - 1).next_power_of_two() + 1;
        let span = (long - 1) as f64;
        let spacing = self.spacing_m * span / (side - 1) as f64;
        let mut data = Vec::with_capacity(side * side);
        for j in 0..side {
            for i in 0..side {
                let (x, y) = (i as f64 * span / (side - 1) as f64, j as f64 * span / (side - 1) as f64);
                data.push(self.bilinear(x, y));
            }
        }
        Heightfield { width: side, height: side, spacing_m: spacing, data, geo: self.geo }
    }

    /// Bilinear height at (x, y) samples, the edge samples held beyond the grid.
    fn bilinear(&self, x: f64, y: f64) -> f32 {
        let cx = |v: f64| (v.floor() as usize).min(self.width - 1);
        let cy = |v: f64| (v.floor() as usize).min(self.height - 1);
        let (x0, y0) = (cx(x), cy(y));
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = ((x - x0 as f64).clamp(0.0, 1.0) as f32, (y - y0 as f64).clamp(0.0, 1.0) as f32);
        let a = self.at(x0, y0) + (self.at(x1, y0) - self.at(x0, y0)) * fx;
        let b = self.at(x0, y1) + (self.at(x1, y1) - self.at(x0, y1)) * fx;
        a + (b - a) * fy
    }

    /// The file of this grid in `format`, named `name` in its sidecar.
    pub fn export(&self, format: Format, name: &str) -> Result<Exported, DemError> {
        let mut bytes = Vec::new();
        let sidecar = match format {
            Format::GeoTiff => {
                let mut c = Cursor::new(Vec::new());
                self.write_tiff(&mut c)?;
                bytes = c.into_inner();
                None
            }
            Format::Png16 | Format::Raw16 => {
                let (values, sidecar) = self.quantise16(name, if format == Format::Png16 { "png16" } else { "raw16le" })?;
                if format == Format::Png16 {
                    let mut enc = png::Encoder::new(&mut bytes, self.width as u32, self.height as u32);
                    enc.set_color(png::ColorType::Grayscale);
                    enc.set_depth(png::BitDepth::Sixteen);
                    let mut w = enc.write_header().map_err(|e| DemError::Format(format!("PNG: {e}")))?;
                    let be: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
                    w.write_image_data(&be).map_err(|e| DemError::Format(format!("PNG: {e}")))?;
                } else {
                    bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
                }
                Some(sidecar)
            }
            Format::Glb => {
                bytes = self.glb()?;
                None
            }
        };
        Ok(Exported { bytes, sidecar })
    }

    /// Writes this grid to `path` in the format of its extension (a PNG's or RAW's sidecar
    /// beside it as `PATH.json`). Returns the sidecar, if any.
    pub fn export_path(&self, path: &Path) -> Result<Option<Sidecar>, DemError> {
        let format = Format::of(path)?;
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let out = self.export(format, &name)?;
        std::fs::write(path, &out.bytes)?;
        if let Some(s) = &out.sidecar {
            let mut json = serde_json::to_string_pretty(s).map_err(|e| DemError::Format(e.to_string()))?;
            json.push('\n');
            std::fs::write(path.with_extension(format!("{}.json", path.extension().and_then(|e| e.to_str()).unwrap_or(""))), json)?;
        }
        Ok(out.sidecar)
    }

    /// The samples as 0..=65535 between the lowest and highest (no-data as 0) and what that
    /// scale is.
    fn quantise16(&self, name: &str, format: &'static str) -> Result<(Vec<u16>, Sidecar), DemError> {
        let (lo, hi) = self.data.iter().filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v as f64), b.max(v as f64)));
        if !lo.is_finite() {
            return Err(DemError::Invalid("no sample has data".into()));
        }
        let unit = if hi > lo { (hi - lo) / 65535.0 } else { 1.0 };
        let values = self.data.iter().map(|&v| if v.is_finite() { ((v as f64 - lo) / unit).round().clamp(0.0, 65535.0) as u16 } else { 0 }).collect();
        let nodata_samples = self.data.iter().filter(|v| !v.is_finite()).count();
        let sidecar =
            Sidecar { file: name.into(), format, width: self.width, height: self.height, spacing_m: self.spacing_m, min_m: lo, max_m: hi, metres_per_unit: unit, nodata_samples };
        Ok((values, sidecar))
    }

    /// A binary glTF 2.0 file of this grid as one mesh: a vertex per sample (x east, y up,
    /// z south, metres, the grid's centre at the origin) with normals from central
    /// differences, two triangles per cell whose four samples have data.
    fn glb(&self) -> Result<Vec<u8>, DemError> {
        let (w, h, s) = (self.width, self.height, self.spacing_m);
        if w < 2 || h < 2 {
            return Err(DemError::Invalid("a mesh needs at least 2 × 2 samples".into()));
        }
        let (cx, cz) = ((w - 1) as f64 * s / 2.0, (h - 1) as f64 * s / 2.0);
        let height = |x: usize, y: usize| {
            let v = self.at(x, y);
            if v.is_finite() { v } else { 0.0 }
        };
        let (mut pos, mut nrm) = (Vec::with_capacity(w * h * 3), Vec::with_capacity(w * h * 3));
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for y in 0..h {
            for x in 0..w {
                let p = [(x as f64 * s - cx) as f32, height(x, y), (y as f64 * s - cz) as f32];
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
                pos.extend(p);
                let (xl, xr, yu, yd) = (x.saturating_sub(1), (x + 1).min(w - 1), y.saturating_sub(1), (y + 1).min(h - 1));
                let dx = (height(xr, y) - height(xl, y)) as f64 / ((xr - xl) as f64 * s);
                let dz = (height(x, yd) - height(x, yu)) as f64 / ((yd - yu) as f64 * s);
                let n = [-dx, 1.0, -dz];
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                nrm.extend(n.map(|c| (c / len) as f32));
            }
        }
        let mut idx: Vec<u32> = Vec::new();
        for y in 0..h - 1 {
            for x in 0..w - 1 {
                let corners = [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)];
                if corners.iter().any(|&(i, j)| !self.at(i, j).is_finite()) {
                    continue;
                }
                let [a, b, c, d] = corners.map(|(i, j)| (j * w + i) as u32);
                // Counter-clockwise seen from above (+y), as glTF's front faces are.
                idx.extend([a, c, b, b, c, d]);
            }
        }
        let mut bin = Vec::new();
        for v in pos.iter().chain(&nrm) {
            bin.extend(v.to_le_bytes());
        }
        let idx_offset = bin.len();
        for i in &idx {
            bin.extend(i.to_le_bytes());
        }
        let (vbytes, ibytes) = (pos.len() * 4, idx.len() * 4);
        let json = serde_json::json!({
            "asset": { "version": "2.0", "generator": "terrain (heights in metres, x east, y up, z south)" },
            "scene": 0,
            "scenes": [{ "nodes": [0] }],
            "nodes": [{ "mesh": 0, "name": "terrain" }],
            "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0, "NORMAL": 1 }, "indices": 2, "mode": 4 }] }],
            "buffers": [{ "byteLength": bin.len() }],
            "bufferViews": [
                { "buffer": 0, "byteOffset": 0, "byteLength": vbytes, "target": 34962 },
                { "buffer": 0, "byteOffset": vbytes, "byteLength": vbytes, "target": 34962 },
                { "buffer": 0, "byteOffset": idx_offset, "byteLength": ibytes, "target": 34963 }
            ],
            "accessors": [
                { "bufferView": 0, "componentType": 5126, "count": w * h, "type": "VEC3", "min": lo, "max": hi },
                { "bufferView": 1, "componentType": 5126, "count": w * h, "type": "VEC3" },
                { "bufferView": 2, "componentType": 5125, "count": idx.len(), "type": "SCALAR" }
            ]
        });
        let mut json = json.to_string().into_bytes();
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let total = 12 + 8 + json.len() + 8 + bin.len();
        let mut out = Vec::with_capacity(total);
        out.write_all(b"glTF")?;
        out.write_all(&2u32.to_le_bytes())?;
        out.write_all(&(total as u32).to_le_bytes())?;
        out.write_all(&(json.len() as u32).to_le_bytes())?;
        out.write_all(b"JSON")?;
        out.write_all(&json)?;
        out.write_all(&(bin.len() as u32).to_le_bytes())?;
        out.write_all(b"BIN\0")?;
        out.write_all(&bin)?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Heightfield {
        let (w, h) = (5, 3);
        let mut data: Vec<f32> = (0..w * h).map(|k| 100.0 + (k % w) as f32 * 10.0 - (k / w) as f32 * 4.0).collect();
        data[7] = f32::NAN;
        Heightfield::new(w, h, 32.0, data)
    }

    /// A 16-bit PNG and a RAW of the same grid hold the same values; read back with the
    /// sidecar's scale they give every sample to within half a unit (the lowest and highest
    /// exactly), no-data as 0 and counted.
    #[test]
    fn png16_and_raw16_with_their_sidecar_give_the_heights_back() {
        let g = grid();
        let png = g.export(Format::Png16, "g.png").unwrap();
        let raw = g.export(Format::Raw16, "g.raw").unwrap();
        let s = png.sidecar.clone().unwrap();
        assert_eq!((s.width, s.height, s.spacing_m, s.min_m, s.max_m, s.nodata_samples), (5, 3, 32.0, 92.0, 140.0, 1));
        let back = Heightfield::read_png(Cursor::new(png.bytes), crate::dem::PngScale { metres_per_unit: s.metres_per_unit, offset_m: s.min_m }, 32.0).unwrap();
        let raw_values: Vec<u16> = raw.bytes.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
        assert_eq!(raw.sidecar.unwrap().format, "raw16le");
        for (k, (&want, &got)) in g.data.iter().zip(&back.data).enumerate() {
            let from_raw = (s.min_m + raw_values[k] as f64 * s.metres_per_unit) as f32;
            assert_eq!(got, from_raw, "sample {k}");
            if want.is_finite() {
                assert!((got - want).abs() <= (s.metres_per_unit / 2.0) as f32 + 1e-4, "sample {k}: {got} vs {want}");
            } else {
                assert_eq!(raw_values[k], 0);
            }
        }
    }

    /// The binary glTF is a valid container (magic, version, lengths, 4-byte aligned chunks)
    /// whose JSON names a mesh of one vertex per sample with unit normals and POSITION min/max
    /// equal to the data's; every index is a vertex, and cells with a no-data corner have no
    /// triangles (8 cells, 4 of them touch the hole: 8 triangles).
    #[test]
    fn the_glb_is_a_mesh_of_the_grid() {
        let g = grid();
        let b = g.export(Format::Glb, "g.glb").unwrap().bytes;
        assert_eq!(&b[0..4], b"glTF");
        assert_eq!(u32::from_le_bytes(b[4..8].try_into().unwrap()), 2);
        assert_eq!(u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize, b.len());
        let jlen = u32::from_le_bytes(b[12..16].try_into().unwrap()) as usize;
        assert_eq!((&b[16..20], jlen % 4), (&b"JSON"[..], 0));
        let json: serde_json::Value = serde_json::from_slice(&b[20..20 + jlen]).unwrap();
        let bin_at = 20 + jlen;
        let blen = u32::from_le_bytes(b[bin_at..bin_at + 4].try_into().unwrap()) as usize;
        assert_eq!(&b[bin_at + 4..bin_at + 8], b"BIN\0");
        let bin = &b[bin_at + 8..bin_at + 8 + blen];
        let acc = &json["accessors"];
        assert_eq!(acc[0]["count"], 15);
        assert_eq!(acc[2]["count"], 8 * 3);
        assert_eq!(acc[0]["max"][1], 140.0);
        let floats: Vec<f32> = bin[..15 * 24].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
        for n in floats[45..].chunks_exact(3) {
            assert!(((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt() - 1.0).abs() < 1e-5);
        }
        let idx_at = json["bufferViews"][2]["byteOffset"].as_u64().unwrap() as usize;
        let idx: Vec<u32> = bin[idx_at..idx_at + 24 * 4].chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect();
        assert!(idx.iter().all(|&i| i < 15 && i != 7), "{idx:?}");
    }

    /// A GeoTIFF export reads back exactly: every height bit for bit, no-data as NaN at the
    /// same samples, the spacing, and the place (tiepoint and CRS) of a georeferenced grid.
    #[test]
    fn a_geotiff_export_reads_back_bit_for_bit_with_its_spacing_and_place() {
        let mut g = grid();
        g.data[3] = 1_234.567_9;
        g.geo = Some(crate::dem::GeoRef { origin_m: [655_360.0, 5_242_880.0], epsg: Some(32632) });
        let bytes = g.export(Format::GeoTiff, "g.tif").unwrap().bytes;
        let back = Heightfield::read_tiff(Cursor::new(bytes), 1.0).unwrap();
        assert_eq!((back.width, back.height, back.spacing_m), (5, 3, 32.0));
        let bits = |h: &Heightfield| h.data.iter().map(|v| if v.is_nan() { u32::MAX } else { v.to_bits() }).collect::<Vec<_>>();
        assert_eq!(bits(&back), bits(&g));
        assert_eq!(back.geo, g.geo);
    }

    /// A 300 × 200 grid becomes a 513² square over its 299-cell span (spacing 32 × 299 / 512 m)
    /// whose corners are the grid's corners exactly.
    #[test]
    fn pow2_plus_1_resamples_over_the_longer_span() {
        let g = Heightfield::new(300, 200, 32.0, (0..300 * 200).map(|k| (k % 300) as f32 + (k / 300) as f32 * 1000.0).collect());
        let r = g.to_pow2_plus_1();
        assert_eq!((r.width, r.height), (513, 513));
        assert!((r.spacing_m - 32.0 * 299.0 / 512.0).abs() < 1e-12);
        assert_eq!(r.at(0, 0), g.at(0, 0));
        assert_eq!(r.at(512, 0), g.at(299, 0));
        assert_eq!(r.at(512, 512), g.at(299, 199), "held beyond the shorter side");
        assert_eq!(Format::of(Path::new("a.R16")).unwrap(), Format::Raw16);
        assert!(Format::of(Path::new("a.jpg")).is_err());
    }
}
