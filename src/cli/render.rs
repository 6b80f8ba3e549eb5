//! `terrain render`: a share link's view drawn into a PNG, as the page draws it.

use std::path::{Path, PathBuf};

use super::tem::weights_dir;

/// Frames the page's core may take to make a link's view whole.
const MAX_FRAMES: usize = 5_000;

/// `--size WIDTHxHEIGHT`: 16 to 4096 pixels each way.
pub(crate) fn picture_size(s: &str) -> Result<[u32; 2], String> {
    let (w, h) = s.split_once(['x', 'X', '×']).ok_or_else(|| format!("--size takes WIDTHxHEIGHT, not '{s}'"))?;
    let px = |v: &str| v.trim().parse::<u32>().ok().filter(|p| (16..=4096).contains(p)).ok_or_else(|| format!("--size {s}: each side must be 16 to 4096 pixels"));
    Ok([px(w)?, px(h)?])
}

/// The page options (after `?`) and link fragment (after `#`) of a whole address or a bare
/// fragment.
pub(crate) fn split_link(link: &str) -> (&str, &str) {
    let (before, fragment) = link.split_once('#').unwrap_or(("", link));
    let query = before.split_once('?').map_or("", |(_, q)| q);
    (query, fragment)
}

/// `terrain render`.
pub(crate) fn render(link: &str, size: [u32; 2], out: &Path, weights: Option<PathBuf>, threads: usize, repeats: usize) -> Result<(), String> {
    let (query, fragment) = split_link(link);
    let s = terrain::app::native::still(fragment, query, weights_dir(weights), size, threads.max(1), MAX_FRAMES, repeats)?;
    let file = std::fs::File::create(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), s.width, s.height);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    enc.write_header().and_then(|mut w| w.write_image_data(&s.rgba)).map_err(|e| format!("{}: {e}", out.display()))?;
    let ms: Vec<String> = s.draw_ms.iter().map(|m| format!("{m:.1}")).collect();
    println!("wrote {}: {}×{}, {} nodes, view whole after {} frames; drawn on {} in {} ms", out.display(), s.width, s.height, s.nodes, s.frames, s.adapter, ms.join(", "));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--size` takes 640x480 and 640×480; refuses 8x8, 640 and 640xabc.
    #[test]
    fn picture_size_takes_width_x_height_of_16_to_4096() {
        assert_eq!(picture_size("640x480"), Ok([640, 480]));
        assert_eq!(picture_size("640×480"), Ok([640, 480]));
        assert!(picture_size("8x8").is_err() && picture_size("640").is_err() && picture_size("640xabc").is_err());
    }

    /// A whole address splits into its page options and fragment; a bare fragment has no
    /// options.
    #[test]
    fn a_link_splits_into_query_and_fragment() {
        assert_eq!(split_link("http://h/p/?tem=off#v=2&seed=1"), ("tem=off", "v=2&seed=1"));
        assert_eq!(split_link("v=2&seed=1"), ("", "v=2&seed=1"));
        assert_eq!(split_link("#v=2"), ("", "v=2"));
    }
}
