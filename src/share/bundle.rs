//! World bundles: a link and the terrain pinned into its world, in one file, for worlds whose
//! pins are too large for a link. Whoever opens the file sees the same world: the link's view
//! and settings with the same pinned tiles (a world is a pure function of seed, weights and
//! pins).
//!
//! Format: gzip of one JSON object,
//! `{"format": "terrain-world-bundle", "version": 2, "link": FRAGMENT, "pins": [{"i": I, "j": J,
//! "heights": BASE64}, …]}`: the link's fragment (without `#`), and per pinned tile its tile
//! coordinate and its 32 m heights ([`TILE_SAMPLES`]² little-endian float32, metres, row-major)
//! in standard base64. A tile that keeps its own detail ([`crate::world::pins`]) has, instead
//! of `heights`, `"level": K, "detail": BASE64`: its heights at TEM level K
//! ([`detail_side`]`(K)`² float32), whose box means give the coarser levels and the 32 m tile.
//! Version 1 (32 m heights only) is read too.

use std::io::Read;

use base64::Engine;
use base64::engine::general_purpose::STANDARD;

use crate::grid::{TILE_SAMPLES, TileCoord};
use crate::world::pins::{MAX_DETAIL_SAMPLES, MAX_PINNED_TILES, PinnedTile, Pins, detail_side};

/// The `format` a bundle states.
pub const FORMAT: &str = "terrain-world-bundle";
/// The bundle version this page writes (it reads 1 too).
pub const VERSION: u32 = 2;
/// The file name the page offers a bundle under.
pub const FILE_NAME: &str = "terrain-world.json.gz";
/// Largest bundle read (bytes of the file): 192 MiB. The most pins a world holds,
/// [`MAX_PINNED_TILES`] tiles with [`MAX_DETAIL_SAMPLES`] of detail (133 MiB of float32),
/// compress to less.
pub const MAX_FILE_BYTES: f64 = 192.0 * 1024.0 * 1024.0;
/// Largest inflated bundle (bytes): [`MAX_PINNED_TILES`] tiles and [`MAX_DETAIL_SAMPLES`] in
/// base64, and the link.
const MAX_JSON_BYTES: u64 = ((MAX_PINNED_TILES * TILE_SAMPLES * TILE_SAMPLES + MAX_DETAIL_SAMPLES) * 4 / 3 * 4 + 1024 * 1024) as u64;

/// Why a file is not a world bundle this page can open.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum BundleError {
    /// Not gzip, or truncated.
    #[error("it is not a gzip file or it is cut short ({0})")]
    Gzip(String),
    /// Inflated, it is larger than any bundle.
    #[error("it inflates to more than {0} bytes, more than any world bundle")]
    TooLarge(u64),
    /// Not the bundle's JSON.
    #[error("it is not a world bundle ({0})")]
    Json(String),
    /// Another format or version.
    #[error("it is a {format} file of version {version}; this page opens {FORMAT} versions 1 to {VERSION}")]
    Version {
        /// The format it states.
        format: String,
        /// The version it states.
        version: u32,
    },
    /// A pinned tile that cannot be pinned (which, why).
    #[error("pinned tile {i}, {j}: {why}")]
    Pin {
        /// Its column.
        i: i32,
        /// Its row.
        j: i32,
        /// Why.
        why: String,
    },
    /// More pinned tiles than a world holds, or one tile twice.
    #[error("{0}")]
    Pins(String),
}

#[derive(serde::Serialize, serde::Deserialize)]
struct Json {
    format: String,
    version: u32,
    link: String,
    pins: Vec<JsonPin>,
}

#[derive(serde::Serialize, serde::Deserialize)]
struct JsonPin {
    i: i32,
    j: i32,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    heights: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    level: Option<usize>,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    detail: String,
}

/// Little-endian float32 bytes in standard base64.
fn encode(heights: &[f32]) -> String {
    STANDARD.encode(heights.iter().flat_map(|h| h.to_le_bytes()).collect::<Vec<u8>>())
}

/// A link and the terrain pinned into its world.
#[derive(Clone, Debug, PartialEq)]
pub struct WorldBundle {
    /// The link's fragment (without `#`).
    pub link: String,
    /// The pinned tiles.
    pub pins: Pins,
}

impl WorldBundle {
    /// The bundle as a file (gzip of its JSON).
    pub fn to_bytes(&self) -> Vec<u8> {
        let pins = self
            .pins
            .iter()
            .map(|(c, t)| match t.detail.last() {
                Some(d) => JsonPin { i: c.i, j: c.j, heights: String::new(), level: Some(t.detail.len() - 1), detail: encode(d) },
                None => JsonPin { i: c.i, j: c.j, heights: encode(&t.fine), level: None, detail: String::new() },
            })
            .collect();
        let json = serde_json::to_vec(&Json { format: FORMAT.into(), version: VERSION, link: self.link.clone(), pins }).expect("a bundle is plain JSON");
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        std::io::Write::write_all(&mut gz, &json).expect("writing to memory");
        gz.finish().expect("writing to memory")
    }

    /// The bundle in `bytes`, or why it is not one: read with bounded memory (inflated at most
    /// to what the largest bundle needs), every pinned tile whole and finite, at most
    /// [`MAX_PINNED_TILES`], none twice.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, BundleError> {
        let mut json = Vec::new();
        flate2::read::GzDecoder::new(bytes).take(MAX_JSON_BYTES + 1).read_to_end(&mut json).map_err(|e| BundleError::Gzip(e.to_string()))?;
        if json.len() as u64 > MAX_JSON_BYTES {
            return Err(BundleError::TooLarge(MAX_JSON_BYTES));
        }
        let parsed: Json = serde_json::from_slice(&json).map_err(|e| BundleError::Json(e.to_string()))?;
        if parsed.format != FORMAT || !(1..=VERSION).contains(&parsed.version) {
            return Err(BundleError::Version { format: parsed.format, version: parsed.version });
        }
        if parsed.pins.len() > MAX_PINNED_TILES {
            return Err(BundleError::Pins(format!("{} pinned tiles, more than a world holds ({MAX_PINNED_TILES})", parsed.pins.len())));
        }
        let mut pins = Pins::new();
        for p in parsed.pins {
            let c = TileCoord::new(p.i, p.j);
            let err = |why: String| BundleError::Pin { i: p.i, j: p.j, why };
            if pins.contains(c) {
                return Err(BundleError::Pins(format!("tile {}, {} is pinned twice", p.i, p.j)));
            }
            let floats = |b64: &str, what: &str, want: usize| -> Result<Vec<f32>, BundleError> {
                let raw = STANDARD.decode(b64.as_bytes()).map_err(|e| err(format!("its {what} are not base64 ({e})")))?;
                if raw.len() != want * 4 {
                    return Err(err(format!("{} bytes of {what}, not {}", raw.len(), want * 4)));
                }
                Ok(raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
            };
            let tile = match p.level {
                None => PinnedTile::new(floats(&p.heights, "heights", TILE_SAMPLES * TILE_SAMPLES)?),
                Some(k) if k < crate::models::tem::LEVELS => PinnedTile::with_detail(k, floats(&p.detail, "detail", detail_side(k).pow(2))?),
                Some(k) => return Err(err(format!("detail level {k} is not a TEM level"))),
            };
            pins.insert_tile(c, tile.map_err(err)?).map_err(err)?;
        }
        Ok(Self { link: parsed.link, pins })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bundle(tiles: usize) -> WorldBundle {
        let mut pins = Pins::new();
        for t in 0..tiles {
            let heights = (0..TILE_SAMPLES * TILE_SAMPLES).map(|p| 1000.0 + (p as f32 * 0.37 + t as f32).sin() * 300.0 + p as f32 * 1e-3).collect();
            pins.insert(TileCoord::new(t as i32 - 1, 2), heights).unwrap();
        }
        WorldBundle { link: "v=2&seed=9&src=tcm&cam=1,2,3,0,-0.5".into(), pins }
    }

    /// A bundle read back is the same link and the same pins, every height bit for bit; four
    /// tiles (256 KiB of heights) make a file of less than 400 KiB.
    #[test]
    fn a_bundle_reads_back_bit_for_bit() {
        let b = bundle(4);
        let bytes = b.to_bytes();
        eprintln!("4 pinned tiles: {} bytes", bytes.len());
        assert!(bytes.len() < 400 * 1024, "{}", bytes.len());
        let back = WorldBundle::from_bytes(&bytes).unwrap();
        assert_eq!(back.link, b.link);
        for ((c, t), (c2, t2)) in b.pins.iter().zip(back.pins.iter()) {
            assert_eq!(c, c2);
            assert!(t.fine.iter().zip(t2.fine.iter()).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
        assert_eq!(back.pins.coords().len(), 4);
    }

    /// Files that are not bundles are refused with what is wrong: not gzip, truncated, other
    /// JSON, another version, a tile of the wrong size, NaN heights, a tile twice, too many
    /// tiles, and a gzip bomb that inflates past the largest bundle (read no further).
    #[test]
    fn broken_and_hostile_bundles_are_refused_with_the_reason() {
        let gz = |json: &str| {
            let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
            std::io::Write::write_all(&mut e, json.as_bytes()).unwrap();
            e.finish().unwrap()
        };
        let tile = |h: f32| STANDARD.encode((0..TILE_SAMPLES * TILE_SAMPLES).flat_map(|_| h.to_le_bytes()).collect::<Vec<u8>>());
        let good = bundle(1).to_bytes();
        let many: Vec<String> = (0..=MAX_PINNED_TILES).map(|k| format!(r#"{{"i":{k},"j":0,"heights":""}}"#)).collect();
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"GIF89a".to_vec(), "not a gzip file"),
            (good[..good.len() / 2].to_vec(), "cut short"),
            (gz(r#"{"seed": 1}"#), "not a world bundle"),
            (gz(r#"{"format":"terrain-world-bundle","version":7,"link":"","pins":[]}"#), "version 7"),
            (gz(r#"{"format":"terrain-world-bundle","version":1,"link":"","pins":[{"i":0,"j":0,"heights":"AAAA"}]}"#), "3 bytes of heights"),
            (gz(&format!(r#"{{"format":"terrain-world-bundle","version":1,"link":"","pins":[{{"i":0,"j":1,"heights":"{}"}}]}}"#, tile(f32::NAN))), "pinned tile 0, 1"),
            (
                gz(&format!(r#"{{"format":"terrain-world-bundle","version":1,"link":"","pins":[{{"i":0,"j":0,"heights":"{0}"}},{{"i":0,"j":0,"heights":"{0}"}}]}}"#, tile(5.0))),
                "pinned twice",
            ),
            (gz(&format!(r#"{{"format":"terrain-world-bundle","version":1,"link":"","pins":[{}]}}"#, many.join(","))), "more than a world holds"),
            (gz(&" ".repeat(MAX_JSON_BYTES as usize + 10)), "inflates to more than"),
        ];
        for (bytes, needle) in cases {
            let e = WorldBundle::from_bytes(&bytes).unwrap_err().to_string();
            assert!(e.contains(needle), "{e} (wanted '{needle}')");
        }
    }

    /// A pin with its own 8 m detail travels as that detail: read back, every level and the
    /// 32 m tile are bit for bit the pin's; a version-1 bundle (32 m heights only) still opens;
    /// detail of the wrong size or of a level the TEM lacks is refused with the reason.
    #[test]
    fn a_bundle_carries_a_pins_own_detail_and_version_1_bundles_still_open() {
        let n = 520;
        let dem = crate::dem::Heightfield::new(n, n, 8.0, (0..n * n).map(|k| 900.0 + ((k % n) as f32 * 0.7).sin() * 5.0 + (k / n) as f32 * 0.2).collect());
        let mut pins = Pins::new();
        pins.add(&dem, TileCoord::new(3, 4)).unwrap();
        let b = WorldBundle { link: "v=2&seed=1".into(), pins };
        let bytes = b.to_bytes();
        eprintln!("one tile with 8 m detail: {} bytes", bytes.len());
        let back = WorldBundle::from_bytes(&bytes).unwrap();
        let (t, t2) = (b.pins.get(TileCoord::new(3, 4)).unwrap(), back.pins.get(TileCoord::new(3, 4)).unwrap());
        assert_eq!(t2.detail.len(), 2);
        let same = |a: &[f32], b: &[f32]| a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        assert!(same(&t.fine, &t2.fine) && same(&t.coarse, &t2.coarse));
        assert!((0..2).all(|k| same(t.detail(k).unwrap(), t2.detail(k).unwrap())));
        let gz = |json: String| {
            let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
            std::io::Write::write_all(&mut e, json.as_bytes()).unwrap();
            e.finish().unwrap()
        };
        let v1 = gz(format!(r#"{{"format":"terrain-world-bundle","version":1,"link":"seed=3","pins":[{{"i":0,"j":0,"heights":"{}"}}]}}"#, encode(&t.fine)));
        let old = WorldBundle::from_bytes(&v1).unwrap();
        assert!(same(&old.pins.get(TileCoord::new(0, 0)).unwrap().fine, &t.fine) && old.pins.get(TileCoord::new(0, 0)).unwrap().detail.is_empty());
        for (pin, needle) in
            [(format!(r#""level":1,"detail":"{}""#, encode(&t.fine)), "of detail, not 1048576"), (r#""level":7,"detail":"""#.to_string(), "level 7 is not a TEM level")]
        {
            let e = WorldBundle::from_bytes(&gz(format!(r#"{{"format":"terrain-world-bundle","version":2,"link":"","pins":[{{"i":0,"j":0,{pin}}}]}}"#))).unwrap_err().to_string();
            assert!(e.contains(needle), "{e} (wanted '{needle}')");
        }
    }
}
