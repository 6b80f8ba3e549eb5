//! `terrain`: the command-line side of the terrain tool.
//!
//! `terrain world --seed S --tiles X0 Y0 W H --out region.tif [--source procedural]`
//! writes the 32 m heights (metres) of tiles [X0, X0+W) × [Y0, Y0+H) as a float32 TIFF.

use std::process::ExitCode;

use terrain::world::{NoiseParams, ProceduralSource, TileSource, export};

const USAGE: &str = "usage:\n  terrain world --seed S --tiles X0 Y0 W H --out region.tif [--source procedural]";

fn world(args: &[String]) -> Result<(), String> {
    let mut seed: Option<u64> = None;
    let mut tiles: Option<(i32, i32, u32, u32)> = None;
    let mut out: Option<String> = None;
    let mut source = "procedural".to_string();
    let mut it = args.iter();
    let num = |v: Option<&String>, what: &str| -> Result<i64, String> {
        let v = v.ok_or_else(|| format!("{what} is missing"))?;
        v.parse::<i64>().map_err(|_| format!("{what} '{v}' is not a whole number"))
    };
    while let Some(a) = it.next() {
        match a.as_str() {
            "--seed" => {
                let v = it.next().ok_or("--seed needs a value")?;
                seed = Some(v.parse().map_err(|_| format!("seed '{v}' is not a whole number ≥ 0"))?);
            }
            "--tiles" => {
                let x0 = num(it.next(), "X0")?;
                let y0 = num(it.next(), "Y0")?;
                let w = num(it.next(), "W")?;
                let h = num(it.next(), "H")?;
                if w < 1 || h < 1 || w * h > 4096 {
                    return Err(format!("W×H must be between 1 and 4096 tiles, got {w}×{h}"));
                }
                if [x0, y0, x0 + w, y0 + h].iter().any(|v| v.abs() > i32::MAX as i64 / 2) {
                    return Err("tile coordinates are out of range".into());
                }
                tiles = Some((x0 as i32, y0 as i32, w as u32, h as u32));
            }
            "--out" => out = Some(it.next().ok_or("--out needs a path")?.clone()),
            "--source" => source = it.next().ok_or("--source needs a value")?.clone(),
            other => return Err(format!("unknown argument '{other}'")),
        }
    }
    let seed = seed.ok_or("--seed is required")?;
    let (x0, y0, w, h) = tiles.ok_or("--tiles X0 Y0 W H is required")?;
    let out = out.ok_or("--out is required")?;
    let src: Box<dyn TileSource> = match source.as_str() {
        "procedural" => Box::new(ProceduralSource::new(NoiseParams::default())),
        other => return Err(format!("unknown source '{other}' (available: procedural)")),
    };
    let hf = export::region(seed, src, x0, y0, w, h);
    let file = std::fs::File::create(&out).map_err(|e| format!("cannot create {out}: {e}"))?;
    hf.write_tiff(std::io::BufWriter::new(file)).map_err(|e| format!("cannot write {out}: {e}"))?;
    eprintln!("wrote {out}: {}×{} samples at {} m", hf.width, hf.height, hf.spacing_m);
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("world") => world(&args[1..]),
        Some("-h" | "--help") | None => {
            println!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Some(other) => Err(format!("unknown command '{other}'\n{USAGE}")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("terrain: {e}");
            ExitCode::from(2)
        }
    }
}
