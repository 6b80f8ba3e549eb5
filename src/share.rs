//! Share links: the URL fragment that holds the seed, the camera pose and the settings, so the
//! receiver sees the same world from the same place, bit for bit.
//!
//! Format (version 2): `#v=2&seed=S&src=SOURCE&w=HASH&cam=X,Y,Z,YAW,PITCH&r=R&lod=PX&noise=KIND,OCT,PERS,LAC,WAVE,AMP,BASE&auto=V`
//! with metres for positions, radians for angles, tiles for R, pixels for PX and m/s for V.
//! SOURCE is `tcm` (the learned world), `procedural` or `sketch`; HASH names the learned world's
//! weights, or the sketch models' (absent for the procedural world). A sketch world adds
//! `&sk=CODE&relief=M&extent=E`: the sketch ([`crate::sketch::code`]), its relief and its extent
//! (across) in metres (a link without `extent` is an 8 km sketch).
//! Version-1 links (no `src`, no `w`) were made when the world was procedural: they open the
//! procedural world, and the page says the world may differ. Unknown keys are ignored so older pages can open newer links. Keys and values are
//! percent-decoded (`application/x-www-form-urlencoded`, as browsers encode them).
//!
//! The page's query string (`?tem=gpu|cpu|off`) holds options of this page load, not of the
//! world: [`PageOptions`].

pub mod bundle;

use crate::models::runtime::TemChoice;
use crate::world::{NoiseKind, NoiseParams, SourceKind};

/// The link version this page writes.
pub const LINK_VERSION: u32 = 2;
/// Longest weights hash a link may carry (hex digits).
const MAX_HASH_DIGITS: usize = 16;

/// Relevance radius a link may carry and the settings panel offers (tiles): one range, so
/// neither clamps the other's values. The node budget keeps the largest within the GPU's
/// memory ([`crate::render::node_budget`]).
pub const RADIUS_TILES: std::ops::RangeInclusive<f64> = 1.0..=16.0;
/// LOD target (screen pixels per sample) a link may carry and the settings panel offers.
pub const LOD_PX: std::ops::RangeInclusive<f64> = 0.5..=64.0;
/// Autopilot speed (m/s) a link may carry and the settings panel offers.
pub const AUTOPILOT_MPS: std::ops::RangeInclusive<f64> = 0.0..=5000.0;
/// Render scales a link may ask for (`scale=`): the 3-D view's resolution per axis as a
/// fraction of the screen's.
pub const RENDER_SCALE: std::ops::RangeInclusive<f32> = 0.25..=1.0;

/// Everything a link carries.
#[derive(Clone, Debug, PartialEq)]
pub struct ShareState {
    /// World seed.
    pub seed: u64,
    /// Which generator makes the tiles.
    pub source: SourceKind,
    /// Hash of the learned world's weights (hex) the link was made with; `None` for the
    /// procedural world or when not known yet.
    pub weights: Option<String>,
    /// Version of the link this state was read from ([`LINK_VERSION`] for states made here).
    pub link_version: u32,
    /// Camera position (world metres: x east, y up, z south).
    pub position_m: [f64; 3],
    /// Camera heading (radians; 0 looks towards −z, positive turns towards +x).
    pub yaw: f32,
    /// Camera pitch (radians; positive looks up).
    pub pitch: f32,
    /// Relevance radius (tiles).
    pub radius_tiles: f64,
    /// Level-of-detail target: projected vertex spacing in pixels (smaller = more detail).
    pub lod_px: f64,
    /// Procedural noise parameters.
    pub noise: NoiseParams,
    /// Autopilot speed (m/s); 0 when off.
    pub autopilot_mps: f64,
    /// The sketch of a sketch world ([`crate::sketch::code`]); `None` for other worlds or a
    /// sketch world that starts from the page's first example.
    pub sketch: Option<String>,
    /// Relief of a sketch world (metres from its lowest to its highest point).
    pub relief_m: f64,
    /// Extent of a sketch world's sketch (metres across,
    /// [`crate::world::sketched::EXTENT_M`]).
    pub extent_m: f64,
    /// Plain shading (`shade=plain`: colours by elevation and slope, no shadows or detail),
    /// for slow devices; the full shading otherwise.
    pub plain_shading: bool,
    /// The 3-D view's resolution per axis as a fraction of the screen's (`scale=`, within
    /// [`RENDER_SCALE`]), for slow devices; `None` for the page's own choice
    /// ([`crate::render::view_size`]).
    pub render_scale: Option<f32>,
}

impl Default for ShareState {
    fn default() -> Self {
        Self {
            seed: 1,
            source: SourceKind::default(),
            weights: None,
            link_version: LINK_VERSION,
            position_m: [2048.0, 2900.0, 2048.0],
            yaw: 0.6,
            pitch: -0.3,
            radius_tiles: 4.0,
            lod_px: 6.0,
            noise: NoiseParams::default(),
            autopilot_mps: 0.0,
            sketch: None,
            relief_m: crate::world::sketched::DEFAULT_RELIEF_M,
            extent_m: crate::world::sketched::SKETCH_EXTENT_M,
            plain_shading: false,
            render_scale: None,
        }
    }
}

/// Why a fragment could not be read.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("broken share link: {0}")]
pub struct ShareError(pub String);

/// Largest camera heading accepted from a link (radians, either sign); the page keeps its
/// heading in [0, 2π).
pub const MAX_LINK_YAW: f64 = 1000.0;

/// Most characters of a link's text a message quotes.
pub const MAX_QUOTED_CHARS: usize = 32;

/// `text` as a message quotes it: at most [`MAX_QUOTED_CHARS`] characters, control and
/// invisible characters shown as '�', "…" where it was cut (a link's text never runs on in a
/// notice, whatever it says).
pub fn quoted(text: &str) -> String {
    let mut out: String = text
        .chars()
        .take(MAX_QUOTED_CHARS)
        .map(|c| if c.is_control() || matches!(c, '\u{200b}'..='\u{200f}' | '\u{2028}'..='\u{202e}' | '\u{2060}'..='\u{206f}' | '\u{feff}') { '\u{fffd}' } else { c })
        .collect();
    if text.chars().count() > MAX_QUOTED_CHARS {
        out.push('…');
    }
    out
}

fn numbers<const N: usize>(key: &str, value: &str) -> Result<[f64; N], ShareError> {
    let parts: Vec<&str> = value.split(',').collect();
    if parts.len() != N {
        return Err(ShareError(format!("'{}' needs {N} numbers, got {}", quoted(key), parts.len())));
    }
    let mut out = [0f64; N];
    for (slot, p) in out.iter_mut().zip(parts) {
        let v: f64 = p.trim().parse().map_err(|_| ShareError(format!("'{}' has a bad number '{}'", quoted(key), quoted(p))))?;
        if !v.is_finite() {
            return Err(ShareError(format!("'{}' has a non-finite number", quoted(key))));
        }
        *slot = v;
    }
    Ok(out)
}

/// Longest share link the page copies (characters of the fragment): mail and chat apps,
/// and servers with 8 KiB request lines, cut longer addresses.
pub const MAX_LINK_CHARS: usize = 8000;

/// A sketch too detailed for a link of at most [`MAX_LINK_CHARS`].
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("this sketch makes a link of {chars} characters, more than the {MAX_LINK_CHARS} that mail and chat apps keep")]
pub struct LinkTooLong {
    /// Length of the full fragment (characters).
    pub chars: usize,
    /// The fragment with everything but the sketch, to send with the sketch as a file.
    pub without_sketch: String,
}

impl ShareState {
    /// The fragment to hand out: [`Self::to_fragment`], or — when the sketch makes it longer
    /// than [`MAX_LINK_CHARS`] — an error carrying the link without its sketch.
    pub fn share_fragment(&self) -> Result<String, LinkTooLong> {
        let f = self.to_fragment();
        if f.len() <= MAX_LINK_CHARS {
            return Ok(f);
        }
        Err(LinkTooLong { chars: f.len(), without_sketch: ShareState { sketch: None, ..self.clone() }.to_fragment() })
    }

    /// The fragment (without '#') for this state.
    pub fn to_fragment(&self) -> String {
        let n = &self.noise;
        let kind = match n.kind {
            NoiseKind::Fbm => "fbm",
            NoiseKind::Ridged => "ridged",
        };
        // The camera to the centimetre and its angles to 10⁻⁵ rad (0.1 m at 10 km), with no
        // trailing zeros.
        let short = |v: f64, decimals: usize| {
            let t = format!("{v:.decimals$}");
            let t = if t.contains('.') { t.trim_end_matches('0').trim_end_matches('.').to_string() } else { t };
            if t == "-0" { "0".to_string() } else { t }
        };
        let [x, y, z] = self.position_m.map(|c| short(c, 2));
        let (yaw, pitch) = (short(self.yaw as f64, 5), short(self.pitch as f64, 5));
        let mut weights = match (self.source, &self.weights) {
            (SourceKind::Learned | SourceKind::Sketch, Some(h)) => format!("&w={h}"),
            _ => String::new(),
        };
        if self.source == SourceKind::Sketch {
            if let Some(code) = &self.sketch {
                weights.push_str(&format!("&sk={code}"));
            }
            weights.push_str(&format!("&relief={}&extent={}", self.relief_m, self.extent_m));
        }
        // Only the plain shading is said: links made before it existed read as they always did.
        let mut shade = if self.plain_shading { "&shade=plain".to_string() } else { String::new() };
        if let Some(scale) = self.render_scale {
            shade.push_str(&format!("&scale={scale}"));
        }
        format!(
            "v={LINK_VERSION}&seed={}&src={}{weights}&cam={x},{y},{z},{},{}&r={}&lod={}&noise={kind},{},{},{},{},{},{}&auto={}{shade}",
            self.seed,
            self.source.key(),
            yaw,
            pitch,
            self.radius_tiles,
            self.lod_px,
            n.octaves,
            n.persistence,
            n.lacunarity,
            n.wavelength_m,
            n.amplitude_m,
            n.base_m,
            self.autopilot_mps
        )
    }

    /// Reads a fragment (with or without the leading '#'). An empty fragment is the default
    /// world; anything malformed is an error naming the bad part, never a panic.
    pub fn from_fragment(fragment: &str) -> Result<ShareState, ShareError> {
        let f = fragment.strip_prefix('#').unwrap_or(fragment);
        let mut s = ShareState::default();
        if f.trim().is_empty() {
            return Ok(s);
        }
        if let Some(pair) = f.split('&').find(|p| !p.is_empty() && !p.contains('=')) {
            return Err(ShareError(format!("'{}' is not key=value", quoted(pair))));
        }
        for (key, value) in form_urlencoded::parse(f.as_bytes()) {
            let (key, value) = (key.as_ref(), value.as_ref());
            match key {
                "v" => {
                    s.link_version = match value {
                        "1" => 1,
                        "2" => 2,
                        _ => return Err(ShareError(format!("unknown link version '{}'", quoted(value)))),
                    };
                    if s.link_version == 1 {
                        // Version 1 knew only the procedural world.
                        s.source = SourceKind::Procedural;
                    }
                }
                "src" => {
                    s.source = SourceKind::from_key(value).ok_or_else(|| ShareError(format!("unknown world source '{}' (expected tcm, procedural or sketch)", quoted(value))))?
                }
                "w" => {
                    if value.is_empty() || value.len() > MAX_HASH_DIGITS || !value.bytes().all(|b| b.is_ascii_hexdigit()) {
                        return Err(ShareError(format!("weights hash '{}' is not 1..{MAX_HASH_DIGITS} hex digits", quoted(value))));
                    }
                    s.weights = Some(value.to_ascii_lowercase());
                }
                "seed" => s.seed = value.parse().map_err(|_| ShareError(format!("seed '{}' is not a whole number", quoted(value))))?,
                "cam" => {
                    let [x, y, z, yaw, pitch] = numbers::<5>(key, value)?;
                    if [x, y, z].iter().any(|c| c.abs() > 1e9) {
                        return Err(ShareError("camera is too far out (over 10⁹ m)".into()));
                    }
                    if yaw.abs() > MAX_LINK_YAW {
                        return Err(ShareError(format!("camera heading {yaw} rad is outside ±{MAX_LINK_YAW} rad")));
                    }
                    s.position_m = [x, y, z];
                    s.yaw = yaw as f32;
                    s.pitch = (pitch as f32).clamp(-1.55, 1.55);
                }
                "r" => {
                    let [r] = numbers::<1>(key, value)?;
                    if !RADIUS_TILES.contains(&r) {
                        return Err(ShareError(format!("radius {r} is outside {}..{} tiles", RADIUS_TILES.start(), RADIUS_TILES.end())));
                    }
                    s.radius_tiles = r;
                }
                "lod" => {
                    let [px] = numbers::<1>(key, value)?;
                    if !LOD_PX.contains(&px) {
                        return Err(ShareError(format!("lod {px} is outside {}..{} px", LOD_PX.start(), LOD_PX.end())));
                    }
                    s.lod_px = px;
                }
                "noise" => {
                    let (kind, rest) = value.split_once(',').ok_or_else(|| ShareError("'noise' needs a kind and 6 numbers".into()))?;
                    let kind = match kind {
                        "fbm" => NoiseKind::Fbm,
                        "ridged" => NoiseKind::Ridged,
                        other => return Err(ShareError(format!("unknown noise kind '{}'", quoted(other)))),
                    };
                    let [oct, pers, lac, wave, amp, base] = numbers::<6>(key, rest)?;
                    if oct.fract() != 0.0 || !(0.0..=64.0).contains(&oct) {
                        return Err(ShareError(format!("octaves '{}' is not a small whole number", quoted(&oct.to_string()))));
                    }
                    let noise = NoiseParams {
                        kind,
                        octaves: oct as u32,
                        persistence: pers as f32,
                        lacunarity: lac as f32,
                        wavelength_m: wave as f32,
                        amplitude_m: amp as f32,
                        base_m: base as f32,
                    };
                    noise.validate().map_err(ShareError)?;
                    s.noise = noise;
                }
                "sk" => {
                    crate::sketch::code::decode(value).map_err(|e| ShareError(e.to_string()))?;
                    s.sketch = Some(value.to_string());
                }
                "relief" => {
                    let [r] = numbers::<1>(key, value)?;
                    if !crate::world::sketched::RELIEF_M.contains(&r) {
                        return Err(ShareError(format!("relief {r} m is outside 10..8000 m")));
                    }
                    s.relief_m = r;
                }
                "extent" => {
                    let [e] = numbers::<1>(key, value)?;
                    let range = crate::world::sketched::EXTENT_M;
                    if !range.contains(&e) {
                        return Err(ShareError(format!("sketch extent {e} m is outside {}..{} m", range.start(), range.end())));
                    }
                    s.extent_m = e;
                }
                "shade" => {
                    s.plain_shading = match value {
                        "plain" => true,
                        "full" => false,
                        _ => return Err(ShareError(format!("unknown shading '{}' (expected plain or full)", quoted(value)))),
                    }
                }
                "scale" => {
                    let [v] = numbers::<1>(key, value)?;
                    let v = v as f32;
                    if !RENDER_SCALE.contains(&v) {
                        return Err(ShareError(format!("render scale {v} is outside {}..{}", RENDER_SCALE.start(), RENDER_SCALE.end())));
                    }
                    s.render_scale = Some(v);
                }
                "auto" => {
                    let [v] = numbers::<1>(key, value)?;
                    if !AUTOPILOT_MPS.contains(&v) {
                        return Err(ShareError(format!("autopilot speed {v} is outside {}..{} m/s", AUTOPILOT_MPS.start(), AUTOPILOT_MPS.end())));
                    }
                    s.autopilot_mps = v;
                }
                _ => {}
            }
        }
        Ok(s)
    }
}

/// Options of one page load, read from the query string (`?tem=…&world=…`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PageOptions {
    /// Where the TEM runs.
    pub tem: TemChoice,
    /// Where the learned world's networks (the TCM and the ×4 step) run: `?world=gpu`,
    /// `cpu`, `probe` or `auto` (`off` is the TEM's alone).
    pub world: TemChoice,
}

impl PageOptions {
    /// Reads a query string (with or without the leading '?'), percent-decoded, exact keys and
    /// values only (`?xtem=cpu` or `?tem=cpu2` are not `tem=cpu`). Returns the options and a
    /// notice for values it did not understand (those keep their default).
    pub fn from_query(query: &str) -> (PageOptions, Option<String>) {
        let q = query.strip_prefix('?').unwrap_or(query);
        let mut o = PageOptions::default();
        let mut notice = None;
        for (key, value) in form_urlencoded::parse(q.as_bytes()) {
            let (slot, expected) = match key.as_ref() {
                "tem" => (&mut o.tem, "gpu, cpu, off, probe or auto"),
                "world" => (&mut o.world, "gpu, cpu, probe or auto"),
                _ => continue,
            };
            *slot = match value.as_ref() {
                "auto" => TemChoice::Auto,
                "gpu" => TemChoice::Gpu,
                "cpu" => TemChoice::Cpu,
                "off" if key == "tem" => TemChoice::Off,
                "probe" => TemChoice::Probe,
                other => {
                    notice = Some(format!("unknown ?{key}={} (expected {expected}); the page chooses", quoted(other)));
                    TemChoice::Auto
                }
            };
        }
        (o, notice)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A link's text in a message is cut to 32 characters with "…", control characters shown
    /// as '�': a fragment that is a whole sentence (and a URL to elsewhere) does not run on in
    /// the page's notice, in any field that echoes what the link said.
    #[test]
    fn messages_quote_at_most_32_characters_of_the_link() {
        let long = "Your session expired – log in at https://example.invalid/login?next=%2F\u{0007}";
        for fragment in [format!("v={long}"), format!("seed={long}"), format!("src={long}"), long.replace('=', ""), format!("cam=1,2,3,4,{long}")] {
            let e = ShareState::from_fragment(&fragment).unwrap_err().to_string();
            let quoted_part = e.split('\'').nth(1).unwrap_or_default().to_string();
            assert!(quoted_part.chars().count() <= MAX_QUOTED_CHARS + 1, "{e}");
            assert!(e.chars().count() < 120, "{e}");
            assert!(!e.contains("example.invalid/login"), "{e}");
        }
        assert_eq!(quoted("a\u{0007}b"), "a\u{fffd}b");
        assert_eq!(quoted(&"x".repeat(40)), format!("{}…", "x".repeat(32)));
        let (_, notice) = PageOptions::from_query(&format!("?tem={}", "y".repeat(100)));
        assert!(notice.unwrap().chars().count() < 120);
    }

    #[test]
    fn a_noisy_sketch_link_is_too_long_and_falls_back_to_a_short_link_without_the_sketch() {
        let example =
            ShareState { source: SourceKind::Sketch, sketch: Some(crate::sketch::code::encode(&crate::sketch::examples::first().1)), relief_m: 1500.0, ..ShareState::default() };
        assert_eq!(example.share_fragment(), Ok(example.to_fragment()));
        let mut noisy = crate::sketch::Sketch::filled(0);
        for p in 0..crate::sketch::SKETCH_PX * crate::sketch::SKETCH_PX {
            noisy.band[p] = (crate::grid::mix64(p as u64) % 4) as u8;
        }
        let s = ShareState { sketch: Some(crate::sketch::code::encode(&noisy)), ..example };
        let err = s.share_fragment().unwrap_err();
        assert_eq!(err.chars, s.to_fragment().len());
        assert!(err.chars > MAX_LINK_CHARS, "{}", err.chars);
        assert!(err.without_sketch.len() < 400 && !err.without_sketch.contains("sk="), "{}", err.without_sketch);
        let back = ShareState::from_fragment(&err.without_sketch).unwrap();
        assert_eq!((back.source, back.sketch, back.relief_m), (SourceKind::Sketch, None, 1500.0));
    }

    #[test]
    fn a_sketch_link_round_trips_its_sketch_and_relief_and_refuses_broken_ones() {
        let code = crate::sketch::code::encode(&crate::sketch::examples::first().1);
        let s =
            ShareState { source: SourceKind::Sketch, weights: Some("00ff00ff".into()), sketch: Some(code.clone()), relief_m: 2345.5, extent_m: 700.25, ..ShareState::default() };
        let f = s.to_fragment();
        assert!(f.contains("src=sketch") && f.contains(&format!("sk={code}")) && f.contains("relief=2345.5&extent=700.25"), "{f}");
        assert_eq!(ShareState::from_fragment(&f).unwrap(), s);
        let broken = f.replace(&code, &code[..code.len() / 2]);
        let err = ShareState::from_fragment(&broken).unwrap_err();
        assert!(err.0.contains("sketch code"), "{err}");
        let err = ShareState::from_fragment(&f.replace("relief=2345.5", "relief=1e9")).unwrap_err();
        assert!(err.0.contains("relief"), "{err}");
        for bad in ["extent=100", "extent=9000", "extent=NaN"] {
            let err = ShareState::from_fragment(&f.replace("extent=700.25", bad)).unwrap_err();
            assert!(err.0.contains("extent"), "{bad}: {err}");
        }
        let old = ShareState::from_fragment(&f.replace("&extent=700.25", "")).unwrap();
        assert_eq!(old.extent_m, crate::world::sketched::SKETCH_EXTENT_M, "a link without extent is an 8 km sketch");
    }

    /// A link gives back every setting exactly and the camera to the centimetre (angles to
    /// 10⁻⁵ rad), written with no more digits than that; read and written again it is the
    /// same link.
    #[test]
    fn round_trip_is_exact_but_for_the_camera_which_is_to_the_centimetre() {
        let s = ShareState {
            seed: 18_446_744_073_709_551_615,
            source: SourceKind::Learned,
            weights: Some("0123abcd".into()),
            link_version: LINK_VERSION,
            position_m: [-123_456.789_012_345, 1234.5, 0.1 + 0.2],
            yaw: -2.123_456_7,
            pitch: 0.333_333_34,
            radius_tiles: 5.5,
            lod_px: 3.25,
            noise: NoiseParams { kind: NoiseKind::Fbm, octaves: 11, persistence: 0.47, lacunarity: 2.13, wavelength_m: 15_000.5, amplitude_m: 1999.9, base_m: -10.1 },
            autopilot_mps: 250.0,
            sketch: None,
            relief_m: crate::world::sketched::DEFAULT_RELIEF_M,
            extent_m: crate::world::sketched::SKETCH_EXTENT_M,
            plain_shading: true,
            render_scale: Some(0.75),
        };
        let link = s.to_fragment();
        assert!(link.contains("&cam=-123456.79,1234.5,0.3,-2.12346,0.33333&") && link.ends_with("&shade=plain&scale=0.75"), "{link}");
        let back = ShareState::from_fragment(&format!("#{link}")).unwrap();
        assert!(back.position_m.iter().zip(&s.position_m).all(|(a, b)| (a - b).abs() <= 0.005), "{:?}", back.position_m);
        assert!((back.yaw - s.yaw).abs() <= 6e-6 && (back.pitch - s.pitch).abs() <= 6e-6);
        assert_eq!(ShareState { position_m: s.position_m, yaw: s.yaw, pitch: s.pitch, ..back.clone() }, s);
        assert_eq!(back.to_fragment(), link);
        let procedural = ShareState { source: SourceKind::Procedural, weights: None, ..s };
        let link = procedural.to_fragment();
        assert!(link.starts_with("v=2&") && link.contains("&src=procedural&") && !link.contains("&w="), "{link}");
        let again = ShareState::from_fragment(&link).unwrap();
        assert_eq!(ShareState { position_m: procedural.position_m, yaw: procedural.yaw, pitch: procedural.pitch, ..again }, procedural);
    }

    /// A version-1 link (made when the world was procedural) opens the procedural world with
    /// its view, and says it is version 1; a version-2 link names its source and weights.
    #[test]
    fn version_1_links_open_the_procedural_world() {
        let v1 = ShareState::from_fragment("v=1&seed=42&cam=100,2000,300,0.5,-0.2&r=3").unwrap();
        assert_eq!((v1.link_version, v1.source, v1.seed, v1.position_m, v1.weights.as_deref()), (1, SourceKind::Procedural, 42, [100.0, 2000.0, 300.0], None));
        let v2 = ShareState::from_fragment("v=2&seed=42&src=tcm&w=00FF12").unwrap();
        assert_eq!((v2.link_version, v2.source, v2.weights.as_deref()), (2, SourceKind::Learned, Some("00ff12")));
        assert_eq!(ShareState::default().source, SourceKind::Learned, "a page without a link starts on the learned world");
    }

    /// The full shading is the default and is not written into links (links made before the
    /// setting read as they did); `shade=plain` and `shade=full` are read, anything else is
    /// refused with the two it takes.
    #[test]
    fn the_shading_is_in_a_link_only_when_plain() {
        assert!(!ShareState::default().plain_shading && !ShareState::default().to_fragment().contains("shade"));
        assert!(ShareState::from_fragment("v=2&shade=plain").unwrap().plain_shading);
        assert!(!ShareState::from_fragment("v=2&shade=full").unwrap().plain_shading);
        let e = ShareState::from_fragment("v=2&shade=flat").unwrap_err();
        assert!(e.0.contains("'flat'") && e.0.contains("plain or full"), "{e}");
    }

    /// The page's own render scale is the default and is not written into links; `scale=0.5`
    /// is read back as 0.5 and written again; a scale outside 0.25..1 is refused with the range.
    #[test]
    fn the_render_scale_is_in_a_link_only_when_chosen() {
        assert!(ShareState::default().render_scale.is_none() && !ShareState::default().to_fragment().contains("scale"));
        let half = ShareState::from_fragment("v=2&scale=0.5").unwrap();
        assert_eq!(half.render_scale, Some(0.5));
        assert!(half.to_fragment().ends_with("&scale=0.5"), "{}", half.to_fragment());
        let e = ShareState::from_fragment("v=2&scale=2").unwrap_err();
        assert!(e.0.contains("0.25..1"), "{e}");
    }

    #[test]
    fn empty_fragment_is_the_default_world() {
        assert_eq!(ShareState::from_fragment("").unwrap(), ShareState::default());
        assert_eq!(ShareState::from_fragment("#").unwrap(), ShareState::default());
    }

    #[test]
    fn malformed_links_are_errors_not_panics() {
        for bad in [
            "seed=abc",
            "seed=-1",
            "cam=1,2,3",
            "cam=1,2,3,4,NaN",
            "cam=1e300,0,0,0,0",
            "r=0",
            "r=1000",
            "lod=-3",
            "noise=perlin,8,0.5,2,20000,2400,0",
            "noise=fbm,0,0.5,2,20000,2400,0",
            "noise=fbm,8,0.5,2",
            "noise=fbm,2.5,0.5,2,20000,2400,0",
            "v=3&seed=1",
            "src=fractal",
            "src=",
            "w=",
            "w=xyz",
            "w=0123456789abcdef0",
            "justtext",
            "auto=inf",
            "%%%&&==",
            "cam=0,0,0,1e39,0",
            "cam=0,0,0,-1001,0",
            "cam=0,0,0,0,-1e400",
            "r=1e999",
            "noise=fbm,8,0.5,2,1e39,2400,0",
            "seed=%31%32x",
        ] {
            let r = ShareState::from_fragment(bad);
            assert!(r.is_err(), "'{bad}' should be rejected, got {r:?}");
            assert!(!r.unwrap_err().to_string().is_empty());
        }
    }

    /// Browsers may percent-encode a fragment (',' as %2C, ' ' as %20 or '+'): it reads as
    /// the plain one.
    #[test]
    fn percent_encoded_links_read_like_plain_ones() {
        let plain = ShareState::from_fragment("seed=77&cam=10,20,30,1.5,-0.25&noise=ridged,6,0.5,2,9000,1500,-20").unwrap();
        let enc = ShareState::from_fragment("se%65d=77&cam=10%2C20%2C30%2C1.5%2C-0.25&noise=ridged%2C6%2C0.5%2C2%2C9000%2C1500%2C-20").unwrap();
        assert_eq!(enc, plain);
        assert_eq!(plain.seed, 77);
        assert_eq!(ShareState::from_fragment("cam=1,%202,3,0,0").unwrap().position_m, [1.0, 2.0, 3.0]);
    }

    /// Every camera a link can set is finite: the yaw of 1e39 that once gave a NaN camera is
    /// refused, and the largest accepted heading stays finite in f32.
    #[test]
    fn linked_cameras_are_finite() {
        let e = ShareState::from_fragment("cam=0,0,0,1e39,0").unwrap_err().to_string();
        assert!(e.contains("heading"), "{e}");
        let s = ShareState::from_fragment(&format!("cam=0,0,0,{MAX_LINK_YAW},1e30")).unwrap();
        assert!(s.yaw.is_finite() && s.yaw.sin().is_finite() && s.pitch == 1.55);
    }

    /// `?tem=` is read as a parameter: exact key, exact value, percent-decoded; near misses
    /// are not taken for it, unknown values give a notice and the automatic choice.
    #[test]
    fn page_options_read_exact_tem_values() {
        let tem = |q: &str| PageOptions::from_query(q).0.tem;
        assert_eq!(tem(""), TemChoice::Auto);
        assert_eq!(tem("?tem=cpu"), TemChoice::Cpu);
        assert_eq!(tem("?a=1&tem=gpu"), TemChoice::Gpu);
        assert_eq!(tem("?t%65m=off"), TemChoice::Off);
        assert_eq!(tem("?tem=probe"), TemChoice::Probe);
        assert_eq!(tem("?xtem=cpu"), TemChoice::Auto);
        assert_eq!(tem("?tem=cpu2"), TemChoice::Auto);
        assert_eq!(tem("?tem=cpu&tem=off"), TemChoice::Off, "the last value wins");
        assert!(PageOptions::from_query("?tem=cpu2").1.unwrap().contains("cpu2"));
        assert!(PageOptions::from_query("?tem=cpu").1.is_none());
    }

    /// `?world=` is read as `?tem=` is, beside it: gpu, cpu, probe, auto; not off (the learned
    /// world has no networks to switch off), which gives a notice and the automatic choice.
    #[test]
    fn page_options_read_the_world_networks_choice_beside_the_tems() {
        let o = |q: &str| PageOptions::from_query(q).0;
        assert_eq!(o("?world=gpu&tem=cpu"), PageOptions { tem: TemChoice::Cpu, world: TemChoice::Gpu });
        assert_eq!(o("?world=cpu").world, TemChoice::Cpu);
        assert_eq!(o("?world=probe").world, TemChoice::Probe);
        assert_eq!(o("?w%6Frld=gpu").world, TemChoice::Gpu);
        assert_eq!(o("?world=off").world, TemChoice::Auto);
        assert_eq!(o("?worlds=gpu"), PageOptions::default());
        let notice = PageOptions::from_query("?world=off").1.unwrap();
        assert!(notice.contains("?world=off") && notice.contains("gpu, cpu, probe or auto"), "{notice}");
    }

    #[test]
    fn unknown_keys_are_ignored_and_partial_links_keep_defaults() {
        let s = ShareState::from_fragment("seed=9&future=thing").unwrap();
        assert_eq!(s.seed, 9);
        assert_eq!(s.position_m, ShareState::default().position_m);
    }
}
