//! Example sketches to start from, made by the project's extractor ([`super::extract`]) from
//! real DEMs with `terrain sketch-extract` (the commands are in `examples/README.md`).

use super::Sketch;

/// (name, PNG bytes) of the examples, in the order the page lists them.
const FILES: [(&str, &[u8]); 4] = [
    ("Pyrenees", include_bytes!("examples/pyrenees.png")),
    ("Mont Blanc", include_bytes!("examples/montblanc.png")),
    ("Mount St Helens", include_bytes!("examples/sthelens.png")),
    ("Karakoram", include_bytes!("examples/karakoram.png")),
];

/// Every example: (name, sketch).
pub fn all() -> Vec<(&'static str, Sketch)> {
    FILES.iter().map(|(name, bytes)| (*name, Sketch::read_png(std::io::Cursor::new(*bytes)).expect("the examples are sketches (tested)"))).collect()
}

/// The first example (the canvas starts with it).
pub fn first() -> (&'static str, Sketch) {
    let (name, bytes) = FILES[0];
    (name, Sketch::read_png(std::io::Cursor::new(bytes)).expect("the examples are sketches (tested)"))
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_example_is_a_sketch_with_all_four_bands_and_strokes_of_both_kinds() {
        for (name, s) in super::all() {
            for b in 0..4u8 {
                assert!(s.band.contains(&b), "{name}: band {b} missing");
            }
            let (r, v) = s.stroke_cover();
            assert!(r > 0.005 && v > 0.005, "{name}: ridges {r}, valleys {v}");
        }
    }
}
