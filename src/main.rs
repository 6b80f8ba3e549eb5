//! `terrain`: the command-line side of the terrain tool.
//!
//! `terrain world --seed S --tiles X0 Y0 W H --out region.tif [--source procedural]`
//! writes the 32 m heights (metres) of tiles [X0, X0+W) × [Y0, Y0+H) as a float32 TIFF.
//!
//! `terrain enhance --input in.tif --input-res 32 --output-res 1 --out out.tif` refines a DEM
//! with the TEM ladder (the world's patch code path) and writes the same extent at the output
//! spacing. `terrain tem-probe` prints the digest of the fixed probe per level (CPU), which the
//! browser test compares with the page's WebGPU result.

use std::process::ExitCode;

use terrain::world::{NoiseParams, ProceduralSource, TileSource, export};

const USAGE: &str = "usage:
  terrain world --seed S --tiles X0 Y0 W H --out region.tif [--source procedural]
  terrain enhance --input in.tif --input-res 32 --output-res 1 --out out.tif [--weights DIR] [--batch N]
  terrain tem-probe [--weights DIR]
  terrain train-tem --dem-dir DIR [--steps N] [--finetune N] [--checkpoint-every N] [--batch B] [--chain L] [--seed S] [--out weights]
  terrain eval-tem --dem-dir DIR [--weights weights] [--windows N]";

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

/// The weights folder: `--weights`, else `weights/` here, else the crate's own.
fn weights_dir(args: &[String]) -> std::path::PathBuf {
    if let Some(w) = flag(args, "--weights") {
        return w.into();
    }
    let here = std::path::PathBuf::from("weights");
    if here.join("manifest.json").exists() { here } else { std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/weights")) }
}

fn enhance(args: &[String]) -> Result<(), String> {
    use terrain::dem::{Heightfield, PngScale};
    let input = flag(args, "--input").ok_or("--input is required")?;
    let out = flag(args, "--out").ok_or("--out is required")?;
    let input_res: f64 = flag(args, "--input-res").ok_or("--input-res is required")?.parse().map_err(|_| "--input-res must be a number (m per pixel)")?;
    let output_res: f64 = flag(args, "--output-res").ok_or("--output-res is required")?.parse().map_err(|_| "--output-res must be a number (m per pixel)")?;
    let batch: usize = parse_or(args, "--batch", 4)?;
    terrain::enhance::levels_for(input_res, output_res)?;
    let hf = Heightfield::read_path(std::path::Path::new(input), Some(input_res), PngScale::default()).map_err(|e| format!("{input}: {e}"))?;
    let device = burn::tensor::Device::flex();
    let dir = weights_dir(args);
    let tem = terrain::models::tem::TemSet::load_dir(&dir, &device)?;
    let t = std::time::Instant::now();
    let mut last = (usize::MAX, 0);
    let (result, stats) = terrain::enhance::enhance(&hf, input_res, output_res, &tem, batch, &mut |level, done, total| {
        if level != last.0 || done * 10 / total.max(1) != last.1 {
            last = (level, done * 10 / total.max(1));
            eprintln!("level {level} ({} m): {done}/{total} patches", terrain::models::tem::LEVEL_SPACING_M[level]);
        }
    })?;
    let file = std::fs::File::create(out).map_err(|e| format!("cannot create {out}: {e}"))?;
    result.write_tiff(std::io::BufWriter::new(file)).map_err(|e| format!("cannot write {out}: {e}"))?;
    eprintln!(
        "wrote {out}: {}×{} at {} m from {}×{} at {input_res} m; {} patches in {:.1} s ({:.1} ms per patch)",
        result.width, result.height, result.spacing_m, hf.width, hf.height, stats.quads_made, t.elapsed().as_secs_f64(), stats.ms_per_quad()
    );
    Ok(())
}

fn tem_probe(args: &[String]) -> Result<(), String> {
    use terrain::models::tem::{LEVELS, PROBE_SIDE, TemSet, probe_digest, probe_input};
    let device = burn::tensor::Device::flex();
    let tem = TemSet::load_dir(&weights_dir(args), &device)?;
    let digests = (0..LEVELS).map(|k| tem.enhance_blocking(k, probe_input(k), 1, PROBE_SIDE).map(|raw| probe_digest(&raw))).collect::<Result<Vec<_>, _>>()?;
    println!("{}", serde_json::json!({ "backend": "cpu (burn flex)", "levels": digests }));
    Ok(())
}

/// Value of `--name` in `args`, if given.
fn flag<'a>(args: &'a [String], name: &str) -> Option<&'a str> {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).map(String::as_str)
}

fn parse_or<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> Result<T, String> {
    flag(args, name).map_or(Ok(default), |v| v.parse().map_err(|_| format!("{name} '{v}' is not valid")))
}

#[cfg(feature = "train")]
fn train_tem(args: &[String]) -> Result<(), String> {
    use terrain::train::{self, TrainConfig};
    let dir = std::path::PathBuf::from(flag(args, "--dem-dir").ok_or("--dem-dir is required")?);
    let out = std::path::PathBuf::from(flag(args, "--out").unwrap_or("weights"));
    let d = TrainConfig::default();
    let cfg = TrainConfig {
        steps: parse_or(args, "--steps", d.steps)?,
        finetune_steps: parse_or(args, "--finetune", d.finetune_steps)?,
        batch: parse_or(args, "--batch", d.batch)?,
        chain_levels: parse_or(args, "--chain", d.chain_levels)?,
        lr: parse_or(args, "--lr", d.lr)?,
        seed: parse_or(args, "--seed", d.seed)?,
    };
    let dems = train::pairs::load_dems(&dir)?;
    eprintln!("{} DEMs loaded; {cfg:?}", dems.len());
    let device = burn::tensor::Device::flex().autodiff();
    let every: usize = parse_or(args, "--checkpoint-every", 100)?;
    let mut saved: Result<(), String> = Ok(());
    let (models, losses) = train::train_tem(&dems, &cfg, &device, |step, loss, secs, models| {
        if step % 10 == 0 {
            eprintln!("step {step:5}  loss {loss:.5}  {secs:7.1} s");
        }
        // Checkpoints, so a long run stopped early still leaves usable weights.
        if every > 0 && (step + 1) % every == 0 && saved.is_ok() {
            saved = train::save_models(models, &out.join("checkpoint"));
            eprintln!("checkpoint after {} steps", step + 1);
        }
    })?;
    saved?;
    train::save_models(&models, &out)?;
    println!("{}", serde_json::json!({ "steps": cfg.steps, "batch": cfg.batch, "chain_levels": cfg.chain_levels, "lr": cfg.lr, "seed": cfg.seed, "final_l1_per_level_scale_units": losses }));
    Ok(())
}

#[cfg(feature = "train")]
fn eval_tem(args: &[String]) -> Result<(), String> {
    use terrain::train;
    let dir = std::path::PathBuf::from(flag(args, "--dem-dir").ok_or("--dem-dir is required")?);
    let weights = std::path::PathBuf::from(flag(args, "--weights").unwrap_or("weights"));
    let windows: usize = parse_or(args, "--windows", 64)?;
    let device = burn::tensor::Device::flex();
    let models = train::load_models(&weights, &device)?;
    let dems = train::pairs::load_dems(&dir)?;
    let evals = train::eval_levels(&models, &dems, &device, windows);
    println!("level  spacing  data          windows  RMSE bicubic  RMSE TEM   gain   PSNR bicubic  PSNR TEM   TEM RMSE by distance to edge (px: 0,1,2-3,4-7,8-15,16+)");
    for e in &evals {
        let gain = 100.0 * (1.0 - e.rmse_tem / e.rmse_bicubic.max(1e-12));
        let edge: Vec<String> = e.rmse_by_edge_distance.iter().map(|v| format!("{v:.3}")).collect();
        println!(
            "{:5}  {:5} m  {:12}  {:7}  {:10.4} m  {:8.4} m  {:5.1}%  {:9.2} dB  {:7.2} dB  {}",
            e.level, e.spacing_m, if e.real { "real" } else { "self-similar" }, e.windows, e.rmse_bicubic, e.rmse_tem, gain, e.psnr_bicubic, e.psnr_tem, edge.join(" ")
        );
    }
    // Chained from the coarsest input through the `enhance` path.
    let tem = terrain::models::tem::TemSet::from_models(models, &device)?;
    let mut chained = Vec::new();
    // Self-similar ×32: the largest validation regions, native pixels taken as 1 m.
    let big: Vec<&terrain::dem::Heightfield> = dems.iter().map(|d| &d.hf).collect();
    let mut ss: Vec<terrain::dem::Heightfield> = train::validation_windows(&big, 512, 3);
    for w in &mut ss {
        // Self-similar: slopes are kept, so heights scale with the spacing (as in training).
        let f = (1.0 / w.spacing_m) as f32;
        w.data.iter_mut().for_each(|v| *v *= f);
        w.spacing_m = 1.0;
    }
    chained.extend(train::eval_chained(&tem, &ss, 32.0, "self-similar (native px as 1 m)")?);
    // Real lidar ×8: 1 m DEMs, from 8 m.
    let lidar: Vec<&terrain::dem::Heightfield> = dems.iter().filter(|d| d.hf.spacing_m <= 1.0 + 1e-9).map(|d| &d.hf).collect();
    chained.extend(train::eval_chained(&tem, &train::validation_windows(&lidar, 256, 4), 8.0, "real 1 m lidar")?);
    // Real ×2 at 16 m: DEMs of 16 m or finer resampled to 16 m.
    let sixteen: Vec<terrain::dem::Heightfield> = dems.iter().filter(|d| d.hf.spacing_m <= 16.0).filter_map(|d| d.hf.resample_area(16.0).ok()).collect();
    let refs: Vec<&terrain::dem::Heightfield> = sixteen.iter().collect();
    chained.extend(train::eval_chained(&tem, &train::validation_windows(&refs, 256, 4), 32.0, "real (16 m)")?);
    println!();
    println!("chained (terrain enhance path)     in→out     windows  RMSE bicubic  RMSE TEM   gain   PSNR bic  PSNR TEM  seam ratio  TEM RMSE by distance to quad edge (px: 0,1,2-3,4-7,8-15,16+)");
    for e in &chained {
        let gain = 100.0 * (1.0 - e.rmse_tem / e.rmse_bicubic.max(1e-12));
        let edge: Vec<String> = e.rmse_by_quad_edge_distance.iter().map(|v| format!("{v:.3}")).collect();
        println!(
            "{:34} {:>3}→{:<3} m ×{:<3} {:5}  {:10.4} m  {:8.4} m  {:5.1}%  {:7.2}  {:8.2}  {:9.3}  {}",
            e.data, e.input_m, e.output_m, (e.input_m / e.output_m) as u32, e.windows, e.rmse_bicubic, e.rmse_tem, gain, e.psnr_bicubic, e.psnr_tem, e.seam_ratio, edge.join(" ")
        );
    }
    println!("{}", serde_json::json!({ "one_level": evals, "chained": chained }));
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("world") => world(&args[1..]),
        Some("enhance") => enhance(&args[1..]),
        Some("tem-probe") => tem_probe(&args[1..]),
        #[cfg(feature = "train")]
        Some("train-tem") => train_tem(&args[1..]),
        #[cfg(feature = "train")]
        Some("eval-tem") => eval_tem(&args[1..]),
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
