//! The TEM from the command line: `enhance`, `tem-probe`, `tem-export`, `tem-bench`, weight
//! files (`half-weights`, `average-weights`), `train-tem` and `eval-tem`.

#[allow(unused_imports)]
use crate::*;

/// The weights folder: `--weights`, else `weights/` here, else the crate's own.
pub(crate) fn weights_dir(given: Option<PathBuf>) -> PathBuf {
    if let Some(w) = given {
        return w;
    }
    let here = PathBuf::from("weights");
    if here.join("manifest.json").exists() { here } else { PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/weights")) }
}

/// `terrain enhance`: the input's spacing is the file's own where it has one (a conflicting
/// `--input-res` is refused), else `--input-res`.
pub(crate) fn enhance(input: &std::path::Path, input_res: Option<f64>, output_res: f64, out: &std::path::Path, weights: Option<PathBuf>, batch: usize) -> Result<(), String> {
    use terrain::dem::{Heightfield, PngScale};
    terrain::dem::formats::Format::of(out).map_err(|e| e.to_string())?;
    if let Some(r) = input_res {
        terrain::enhance::levels_for(r, output_res).map_err(|e| e.to_string())?;
    }
    let hf = Heightfield::read_user_path(input, input_res, PngScale::default()).map_err(|e| format!("{}: {e}", input.display()))?;
    let input_res = hf.spacing_m;
    let (first, last) = terrain::enhance::levels_for(input_res, output_res).map_err(|e| match e {
        terrain::enhance::EnhanceError::InputRes(_) => {
            format!("{}'s pixels are {input_res} m; the TEM refines 32, 16, 8, 4 or 2 m grids: resample the file to one of them first", input.display())
        }
        e => e.to_string(),
    })?;
    terrain::enhance::output_size(hf.width, hf.height, last - first + 1).map_err(|e| e.to_string())?;
    let tem = terrain::models::tem::TemSet::load_dir(&weights_dir(weights), &terrain::models::tem::Exec::cpu())?;
    let t = std::time::Instant::now();
    let mut last_report = (usize::MAX, 0);
    let (result, stats) = terrain::enhance::enhance(&hf, input_res, output_res, &tem, batch, &mut |level, done, total| {
        if level != last_report.0 || done * 10 / total.max(1) != last_report.1 {
            last_report = (level, done * 10 / total.max(1));
            eprintln!("level {level} ({} m): {done}/{total} patches", terrain::models::tem::LEVEL_SPACING_M[level]);
        }
    })
    .map_err(|e| e.to_string())?;
    result.export_path(out).map_err(|e| save_error(out, e))?;
    match result.geo {
        Some(g) => eprintln!("georeference kept: north-west corner ({}, {}) m, {}", g.origin_m[0], g.origin_m[1], g.epsg.map_or("a local frame".into(), |c| format!("EPSG {c}"))),
        None => eprintln!("no georeference written: the input has none in a projected CRS (a degree grid is converted to metres, its place on Earth is not kept)"),
    }
    eprintln!(
        "wrote {}: {}×{} at {} m from {}×{} at {input_res} m; {} patches in {:.1} s ({:.1} ms per patch)",
        out.display(),
        result.width,
        result.height,
        result.spacing_m,
        hf.width,
        hf.height,
        stats.quads_made,
        t.elapsed().as_secs_f64(),
        stats.ms_per_quad()
    );
    Ok(())
}

pub(crate) fn tem_probe(weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::models::tem::{Exec, LEVELS, PROBE_SIDE, TemSet, probe_input, probe_json};
    let tem = TemSet::load_dir(&weights_dir(weights), &Exec::cpu())?;
    let levels = (0..LEVELS).map(|k| tem.enhance_blocking(k, probe_input(k), 1, PROBE_SIDE)).collect::<Result<Vec<_>, _>>()?;
    println!("{}", probe_json("cpu", &levels, Default::default()));
    Ok(())
}

pub(crate) fn half_weights(input: &std::path::Path, out: &std::path::Path) -> Result<(), String> {
    let bytes = std::fs::read(input).map_err(|e| format!("cannot read {}: {e}", input.display()))?;
    let half = terrain::models::cpu::to_half_burnpack(&bytes).map_err(|e| format!("{}: {e}", input.display()))?;
    std::fs::write(out, &half).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("{}: {} → {} bytes", out.display(), bytes.len(), half.len());
    Ok(())
}

pub(crate) fn average_weights(inputs: &[PathBuf], out: &std::path::Path) -> Result<(), String> {
    let files = inputs.iter().map(|p| std::fs::read(p).map_err(|e| format!("cannot read {}: {e}", p.display()))).collect::<Result<Vec<_>, _>>()?;
    let avg = terrain::models::cpu::average_burnpacks(&files)?;
    std::fs::write(out, &avg).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("{}: the mean of {} weight files", out.display(), files.len());
    Ok(())
}

pub(crate) fn tem_export(weights: Option<PathBuf>, out: &std::path::Path) -> Result<(), String> {
    use terrain::models::tem::{Exec, FEATURE_GAIN, LEVELS, PROBE_SIDE, TemSet, level_scale_m, probe_input};
    let tem = TemSet::load_dir(&weights_dir(weights), &Exec::cpu())?;
    let mut levels = Vec::new();
    for k in 0..LEVELS {
        let output = tem.enhance_blocking(k, probe_input(k), 1, PROBE_SIDE)?;
        levels.push(serde_json::json!({
            "level": k, "scale_m": level_scale_m(k), "feature_gain": FEATURE_GAIN,
            "convs": tem.convs_json(k), "probe_input": probe_input(k), "probe_output": output,
        }));
    }
    let json = serde_json::json!({ "probe_side": PROBE_SIDE, "levels": levels });
    std::fs::write(out, json.to_string()).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("wrote {}", out.display());
    Ok(())
}

pub(crate) fn tem_bench(level: usize, batch: usize, repeats: usize, threads: Option<u32>, gpu: bool, weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::models::tem::{Exec, PROBE_SIDE, TemSet, probe_input};
    let exec = if gpu { Exec::Burn(terrain::models::native_gpu()?) } else { threads.map_or_else(Exec::cpu, |t| Exec::Cpu { threads: t as usize }) };
    let tem = TemSet::load_dir(&weights_dir(weights), &exec)?;
    let input: Vec<f32> = (0..batch).flat_map(|_| probe_input(level)).collect();
    tem.enhance_blocking(level, input.clone(), batch, PROBE_SIDE)?;
    let mut ms: Vec<f64> = (0..repeats)
        .map(|_| {
            let t = std::time::Instant::now();
            tem.enhance_blocking(level, input.clone(), batch, PROBE_SIDE).map(|_| t.elapsed().as_secs_f64() * 1e3 / batch as f64)
        })
        .collect::<Result<_, _>>()?;
    ms.sort_by(f64::total_cmp);
    let kernels = if gpu { "burn wgpu" } else { terrain::models::cpu::Kernels::chosen().widest() };
    println!(
        "{}",
        serde_json::json!({ "level": level, "batch": batch, "repeats": repeats, "backend": tem.backend(), "kernels": kernels, "ms_per_quad": ms[ms.len() / 2], "min_ms_per_quad": ms[0] })
    );
    Ok(())
}

#[cfg(feature = "train")]
pub(crate) fn train_tem(a: TrainArgs) -> Result<(), String> {
    use terrain::train::{self, TrainConfig};
    let out = a.out;
    let d = TrainConfig::default();
    let cfg = TrainConfig {
        steps: a.steps.unwrap_or(d.steps),
        finetune_steps: a.finetune.unwrap_or(d.finetune_steps),
        batch: a.batch.unwrap_or(d.batch),
        chain_levels: a.chain.map_or(d.chain_levels, |c| c as usize),
        lr: a.lr.unwrap_or(d.lr),
        seed: a.seed.unwrap_or(d.seed),
    };
    let dems = train::pairs::load_dems(&a.dem_dir)?;
    eprintln!("{} DEMs loaded; {cfg:?}", dems.len());
    let (device, mut budget) = a.run.start()?;
    let init = match &a.init {
        Some(dir) => Some(train::load_models(dir, &device)?),
        None => None,
    };
    let every = a.checkpoint_every;
    let mut saved: Result<(), String> = Ok(());
    let (mut done, mut step_s, mut rate) = (0, 0.0, StepRate::new(0));
    let (models, losses) = train::train_tem(&dems, &cfg, &device, init, |step, loss, secs, models| {
        (done, step_s) = (step + 1, secs);
        rate.after_step(done, secs);
        if step % 10 == 0 {
            eprintln!("step {step:5}  loss {loss:.5}  {secs:7.1} s");
        }
        // Checkpoints, so a long run stopped early still leaves usable weights.
        if ((every > 0 && (step + 1) % every == 0) || budget.save_due()) && saved.is_ok() {
            saved = train::save_models(models, &out.join("checkpoint"));
            eprintln!("checkpoint after {} steps", step + 1);
        }
        !budget.spent()
    })?;
    saved?;
    train::save_models(&models, &out)?;
    println!(
        "{}",
        serde_json::json!({ "steps": done, "batch": cfg.batch, "chain_levels": cfg.chain_levels, "lr": cfg.lr, "seed": cfg.seed, "final_l1_per_level_scale_units": losses, "backend": a.run.backend, "seconds": step_s, "examples_per_s": rate.examples_per_s(done, step_s, cfg.batch) })
    );
    Ok(())
}

#[cfg(feature = "train")]
pub(crate) fn eval_tem(dir: PathBuf, weights: PathBuf, windows: usize) -> Result<(), String> {
    use terrain::train;
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
            e.level,
            e.spacing_m,
            if e.real { "real" } else { "self-similar" },
            e.windows,
            e.rmse_bicubic,
            e.rmse_tem,
            gain,
            e.psnr_bicubic,
            e.psnr_tem,
            edge.join(" ")
        );
    }
    // Chained from the coarsest input through the `enhance` path.
    let tem = terrain::models::tem::TemSet::from_models(models, &terrain::models::tem::Exec::cpu())?;
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
    println!(
        "chained (terrain enhance path)     in→out     windows  RMSE bicubic  RMSE TEM   gain   PSNR bic  PSNR TEM  seam ratio TEM/bicubic/truth  TEM RMSE by distance to quad edge (px: 0,1,2-3,4-7,8-15,16+)"
    );
    for e in &chained {
        let gain = 100.0 * (1.0 - e.rmse_tem / e.rmse_bicubic.max(1e-12));
        let edge: Vec<String> = e.rmse_by_quad_edge_distance.iter().map(|v| format!("{v:.3}")).collect();
        println!(
            "{:34} {:>3}→{:<3} m ×{:<3} {:5}  {:10.4} m  {:8.4} m  {:5.1}%  {:7.2}  {:8.2}  {:5.3}/{:5.3}/{:5.3}  {}",
            e.data,
            e.input_m,
            e.output_m,
            (e.input_m / e.output_m) as u32,
            e.windows,
            e.rmse_bicubic,
            e.rmse_tem,
            gain,
            e.psnr_bicubic,
            e.psnr_tem,
            e.seam_ratio,
            e.seam_ratio_bicubic,
            e.seam_ratio_truth,
            edge.join(" ")
        );
    }
    println!("{}", serde_json::json!({ "one_level": evals, "chained": chained }));
    Ok(())
}
