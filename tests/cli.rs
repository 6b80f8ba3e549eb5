//! The `terrain` binary as a user runs it: region export, overlap agreement, DEM enhancement,
//! bad arguments.

use std::path::PathBuf;
use std::process::Command;

use terrain::dem::Heightfield;

fn run(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_terrain")).args(args).output().expect("run terrain")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("terrain-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn read(p: &PathBuf) -> Heightfield {
    Heightfield::read_tiff(std::io::BufReader::new(std::fs::File::open(p).unwrap()), 0.0).unwrap()
}

#[test]
fn overlapping_world_exports_agree_bit_for_bit() {
    let (a, b) = (tmp("a.tif"), tmp("b.tif"));
    let oa = run(&["world", "--seed", "5", "--tiles", "-1", "0", "2", "1", "--out", a.to_str().unwrap()]);
    assert!(oa.status.success(), "{}", String::from_utf8_lossy(&oa.stderr));
    let ob = run(&["world", "--seed", "5", "--tiles", "0", "-1", "1", "2", "--source", "procedural", "--out", b.to_str().unwrap()]);
    assert!(ob.status.success(), "{}", String::from_utf8_lossy(&ob.stderr));
    let (ha, hb) = (read(&a), read(&b));
    assert_eq!((ha.width, ha.height, ha.spacing_m), (256, 128, 32.0));
    assert_eq!((hb.width, hb.height), (128, 256));
    // Tile (0, 0): right half of a, bottom half of b.
    for v in 0..128 {
        for u in 0..128 {
            assert_eq!(ha.at(128 + u, v).to_bits(), hb.at(u, 128 + v).to_bits(), "sample ({u},{v})");
        }
    }
    let spread = ha.data.iter().fold((f32::MAX, f32::MIN), |(lo, hi), &h| (lo.min(h), hi.max(h)));
    assert!(spread.1 - spread.0 > 50.0, "terrain should have relief: {spread:?}");
}

#[test]
fn bad_arguments_are_clear_errors() {
    for (args, needle) in [
        (vec!["world", "--seed", "x", "--tiles", "0", "0", "1", "1", "--out", "/tmp/x.tif"], "seed"),
        (vec!["world", "--seed", "1", "--tiles", "0", "0", "0", "1", "--out", "/tmp/x.tif"], "W×H"),
        (vec!["world", "--seed", "1", "--tiles", "0", "0", "1", "1"], "--out"),
        (vec!["world", "--seed", "1", "--tiles", "0", "0", "1", "1", "--out", "/tmp/x.tif", "--source", "magic"], "unknown source"),
        (vec!["fly"], "unknown command"),
        (vec!["enhance", "--input", "/tmp/x.tif", "--input-res", "30", "--output-res", "1", "--out", "/tmp/y.tif"], "--input-res must be one of"),
        (vec!["enhance", "--input", "/tmp/x.tif", "--input-res", "8", "--output-res", "16", "--out", "/tmp/y.tif"], "finer"),
        (vec!["enhance", "--input", "/nonexistent/in.tif", "--input-res", "32", "--output-res", "16", "--out", "/tmp/y.tif"], "/nonexistent/in.tif"),
    ] {
        let o = run(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}

/// `terrain enhance` on a world export with a no-data hole: same extent, 4× the samples per
/// side at 8 m, area means close to the input, the hole kept as no-data.
#[test]
fn enhance_refines_a_dem_to_the_same_extent() {
    let (a, b, c) = (tmp("in.tif"), tmp("hole.tif"), tmp("out.tif"));
    let o = run(&["world", "--seed", "9", "--tiles", "0", "0", "1", "1", "--out", a.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut hf = read(&a).window(10, 20, 70, 50);
    hf.data[5 * 70 + 7] = f32::NAN;
    hf.write_tiff(std::io::BufWriter::new(std::fs::File::create(&b).unwrap())).unwrap();
    let o = run(&["enhance", "--input", b.to_str().unwrap(), "--input-res", "32", "--output-res", "8", "--out", c.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = read(&c);
    assert_eq!((out.width, out.height, out.spacing_m), (280, 200, 8.0));
    assert!(out.at(7 * 4 + 2, 5 * 4 + 1).is_nan());
    assert_eq!(out.data.iter().filter(|v| v.is_nan()).count(), 16);
    let mut worst = 0f32;
    for y in 2..48 {
        for x in 2..68 {
            if hf.at(x, y).is_nan() {
                continue;
            }
            let m: f32 = (0..16).map(|k| out.at(x * 4 + k % 4, y * 4 + k / 4)).sum::<f32>() / 16.0;
            worst = worst.max((m - hf.at(x, y)).abs());
        }
    }
    assert!(worst < 15.0, "4×4 means of the output should stay near the 32 m input: {worst} m");
}
