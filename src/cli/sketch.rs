//! Sketch to terrain from the command line: `sketch`, `sketch-variants`, `sketch-extract`,
//! `sketch-export`, `sketch-bench`, `eval-sketch` and `train-sketch` (generator and VAE).

#[allow(unused_imports)]
use crate::*;

/// The sketch generator from a weights folder.
pub(crate) fn sketch_generator(weights: Option<PathBuf>) -> Result<terrain::models::sketch::SketchGenCpu, String> {
    use terrain::models::sketch::{SketchGenCpu, WEIGHT_FILE};
    let path = weights_dir(weights).join(WEIGHT_FILE);
    let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    SketchGenCpu::from_burnpack(&bytes).map_err(|e| format!("{}: {e}", path.display()))
}

/// The probe of `sketch-export` and `sketch-bench`: the first example sketch's network input
/// with its mirrored margin ([`terrain::models::sketch::PADDED_PX`]², what one view runs).
pub(crate) fn sketch_probe() -> Vec<f32> {
    terrain::models::sketch::with_margin(&terrain::models::sketch::assemble_input(&terrain::sketch::examples::first().1, terrain::models::sketch::FORMAT_EXTENT_M).0)
}

pub(crate) fn sketch_export(weights: Option<PathBuf>, out: &std::path::Path) -> Result<(), String> {
    use terrain::models::sketch::{IN_CHANNELS, MARGIN_PX, PADDED_PX, SketchScratch, WIDTHS, conv_layers};
    let generator = sketch_generator(weights)?;
    let input = sketch_probe();
    let output = generator.forward(&input, PADDED_PX, &mut SketchScratch::default(), 1);
    let layers: Vec<String> = conv_layers().into_iter().map(|(name, _, _)| name).collect();
    let json = serde_json::json!({
        "side": PADDED_PX, "margin": MARGIN_PX, "in_channels": IN_CHANNELS, "widths": WIDTHS, "layers": layers,
        "convs": generator.convs_json(), "probe_input": input, "probe_output": output,
    });
    std::fs::write(out, json.to_string()).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("wrote {}", out.display());
    Ok(())
}

pub(crate) fn sketch_bench(repeats: usize, threads: Option<u32>, weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::models::sketch::{PADDED_PX, SketchScratch};
    let generator = sketch_generator(weights)?;
    let threads = threads.map_or_else(terrain::models::cpu::default_threads, |t| t as usize);
    let input = sketch_probe();
    let mut scratch = SketchScratch::default();
    generator.forward(&input, PADDED_PX, &mut scratch, threads);
    let mut ms: Vec<f64> = (0..repeats)
        .map(|_| {
            let t = std::time::Instant::now();
            std::hint::black_box(generator.forward(&input, PADDED_PX, &mut scratch, threads));
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    println!(
        "{}",
        serde_json::json!({ "threads": threads, "kernels": terrain::models::cpu::Kernels::chosen().widest(), "repeats": repeats, "ms_per_sketch": ms[ms.len() / 2], "min_ms_per_sketch": ms[0] })
    );
    Ok(())
}

pub(crate) fn sketch(
    input: &std::path::Path,
    out: &std::path::Path,
    weights: Option<PathBuf>,
    views: usize,
    metres: Option<(ExportFormat, f64, bool)>,
    extent_m: Option<f64>,
) -> Result<(), String> {
    use terrain::sketch::{SKETCH_PX, Sketch, write_dem_png16};
    if let Some((format, relief_m, _)) = metres {
        format_agrees(out, format)?;
        check_relief(relief_m)?;
    }
    let sk = Sketch::read_path(input).map_err(|e| format!("{}: {e}", input.display()))?;
    // The terrain in metres is the sketch world's, what `terrain world --sketch` pins: the
    // exact (unfused) generator's, the page worker's bits.
    let generator = sketch_generator(weights)?;
    let generator = if metres.is_some() { generator.exact() } else { generator };
    let default_extent = if metres.is_some() { terrain::world::sketched::SKETCH_EXTENT_M } else { terrain::models::sketch::FORMAT_EXTENT_M };
    let extent_m = extent_m.unwrap_or(default_extent);
    if !generator.knows_extent() {
        eprintln!("note: these weights were trained before the extent channel: the terrain is the same at every extent");
    }
    let t = std::time::Instant::now();
    let h = generator.generate_views(&sk, extent_m, views, &mut Default::default(), terrain::models::cpu::default_threads());
    let ms = t.elapsed().as_secs_f64() * 1e3;
    if let Some((_, relief_m, pow2_plus_1)) = metres.filter(|_| extent_m != terrain::world::sketched::SKETCH_EXTENT_M) {
        // A sketch of another extent: its own samples in metres at its own spacing.
        let r = relief_m as f32;
        let metres = h.iter().map(|v| v / 255.0 * r).collect();
        let hf = terrain::dem::Heightfield::new(SKETCH_PX, SKETCH_PX, extent_m / SKETCH_PX as f64, metres);
        eprintln!("the sketch's terrain: {relief_m} m relief ({extent_m} m extent, {} m spacing, {views} views, {ms:.0} ms)", hf.spacing_m);
        return write_heights(hf, out, pow2_plus_1);
    }
    if let Some((_, relief_m, pow2_plus_1)) = metres {
        use terrain::world::sketched::{SKETCH_TILES, SketchSource};
        let world = SketchSource::new(std::sync::Arc::new(h), relief_m);
        let [first, ..] = SKETCH_TILES;
        let hf = export::from_tiles(first.i, first.j, 2, 2, |c| Some(std::sync::Arc::new(world.tile(c)))).ok_or("the sketch's tiles")?;
        eprintln!("the sketch's terrain: {relief_m} m relief ({extent_m} m extent, {views} views, {ms:.0} ms)");
        return write_heights(hf, out, pow2_plus_1);
    }
    let file = std::fs::File::create(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    write_dem_png16(std::io::BufWriter::new(file), SKETCH_PX, &h).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("wrote {}: {SKETCH_PX}×{SKETCH_PX} 16-bit relative heights ({extent_m} m extent, {views} views, {ms:.0} ms)", out.display());
    Ok(())
}

#[cfg(feature = "train")]
#[allow(clippy::too_many_arguments)]
pub(crate) fn train_sketch(
    dem_dir: &std::path::Path,
    steps: usize,
    resume: bool,
    checkpoint: &std::path::Path,
    every: usize,
    cfg: terrain::train::sketch::SketchConfig,
    validation: usize,
    model: SketchModel,
    init: Option<&std::path::Path>,
    run_args: &RunArgs,
    snapshots: bool,
) -> Result<(), String> {
    use terrain::train::{pairs, sketch};
    if !cfg.adversarial.is_finite() || cfg.adversarial < 0.0 {
        return Err(format!("--adversarial must be a finite number ≥ 0, not {}", cfg.adversarial));
    }
    if !(0.0..=1.0).contains(&cfg.format_share) {
        return Err(format!("--format-share must be between 0 and 1, not {}", cfg.format_share));
    }
    if !(0.0..=1.0).contains(&cfg.windows.hand_drawn) {
        return Err(format!("--hand-drawn must be between 0 and 1, not {}", cfg.windows.hand_drawn));
    }
    if !(cfg.lr.is_finite() && cfg.lr > 0.0) {
        return Err(format!("--lr must be a positive number, not {}", cfg.lr));
    }
    for (flag, m) in [("--max-extent-m", cfg.windows.max_extent_m), ("--min-extent-m", cfg.windows.min_extent_m)] {
        if m.is_some_and(|m| !(m.is_finite() && m > 0.0)) {
            return Err(format!("{flag} must be a positive number of metres, not {m:?}"));
        }
    }
    let init = match init {
        Some(dir) => {
            let p = dir.join(terrain::models::sketch::WEIGHT_FILE);
            let bytes = std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()))?;
            Some(terrain::models::sketch::SketchGenCpu::from_burnpack(&bytes).map_err(|e| format!("{}: {e}", p.display()))?)
        }
        None => None,
    };
    let dems = pairs::load_dems(dem_dir)?;
    if let Some(id) = cfg.windows.dems.iter().find(|id| !dems.iter().any(|d| &d.id == *id)) {
        return Err(format!("--dems: {id} is not in {}", dem_dir.join("manifest.json").display()));
    }
    let (device, mut budget) = run_args.start()?;
    let t = std::time::Instant::now();
    if let SketchModel::Vae = model {
        return train_sketch_vae(
            &dems,
            steps,
            resume,
            checkpoint,
            every,
            terrain::train::sketch_vae::VaeConfig { batch: cfg.batch, pool: cfg.pool, crop: cfg.crop, ..Default::default() },
            validation,
            &device,
            &mut budget,
            run_args.backend,
        );
    }
    let mut run = sketch::SketchRun::start(cfg, &dems, &device, resume.then_some(checkpoint), init.as_ref())?;
    let val = sketch::pairs(&dems, pairs::Split::Validation, validation, &run.cfg.windows, 0x5EED);
    // The held-out files of the format's own pairs, scored beside the extracted validation pairs.
    let held_out = match &run.cfg.format_pairs {
        Some(dir) if !run.cfg.format_exclude.is_empty() => {
            let (all, names) = sketch::format_pairs(dir, &[], false)?;
            let ex = &run.cfg.format_exclude;
            all.into_iter().zip(names).filter(|(_, n)| ex.iter().any(|x| n.contains(x.as_str()))).map(|(p, _)| p).collect()
        }
        _ => Vec::new(),
    };
    eprintln!(
        "sketch generator: {} parameters; {:?}; from step {}; pool and {} validation pairs made in {:.1} s",
        run.g.parameters(),
        run.cfg,
        run.progress.step,
        val.len(),
        t.elapsed().as_secs_f64()
    );
    let end = run.progress.step + steps;
    let mut rate = StepRate::new(run.progress.step);
    let mut last = None;
    while run.progress.step < end && !budget.spent() {
        run.step(&dems)?;
        let p = &run.progress;
        rate.after_step(p.step, p.seconds);
        if p.step % 10 == 0 || p.step == end {
            eprintln!("step {:6}  l1 {:.5} (×255 = {:.2}) adv {:.3} disc {:.3} {:.2} s/step", p.step, p.l1, p.l1 * 255.0, p.adv, p.disc, p.seconds / p.step as f64);
        }
        if p.step % every == 0 || p.step == end || budget.checkpoint_due() {
            let v = sketch::validate(&run.cpu()?, &val);
            eprintln!("validation ({} held-out pairs): RMSE {:.3} PSNR {:.2} dB; baseline {:.3} / {:.2} dB", v.pairs, v.rmse, v.psnr, v.rmse_baseline, v.psnr_baseline);
            if !held_out.is_empty() {
                let h = sketch::validate(&run.cpu()?, &held_out);
                eprintln!("held-out format pairs ({}): RMSE {:.3} PSNR {:.2} dB; baseline {:.3} / {:.2} dB", h.pairs, h.rmse, h.psnr, h.rmse_baseline, h.psnr_baseline);
            }
            run.save(checkpoint, Some(&v))?;
            if snapshots {
                // Each checkpoint's generator kept, for a mean of checkpoints afterwards.
                super::keep_snapshot(checkpoint, terrain::models::sketch::WEIGHT_FILE, "gen", p.step)?;
            }
            last = Some(v);
        }
    }
    let p = &run.progress;
    println!(
        "{}",
        serde_json::json!({ "steps": p.step, "seconds": p.seconds, "l1": p.l1, "adv": p.adv, "disc": p.disc, "validation": last, "checkpoint": checkpoint, "backend": run_args.backend, "examples_per_s": rate.examples_per_s(p.step, p.seconds, run.cfg.batch) })
    );
    Ok(())
}

pub(crate) fn sketch_variants(input: &std::path::Path, n: usize, out_dir: &std::path::Path, seed: u64, weights: Option<PathBuf>, views: usize) -> Result<(), String> {
    use terrain::models::sketch_vae::SketchModels;
    use terrain::sketch::{SKETCH_PX, Sketch, write_dem_png16};
    let sk = Sketch::read_path(input).map_err(|e| format!("{}: {e}", input.display()))?;
    let dir = weights_dir(weights);
    let read = |file: &str| std::fs::read(dir.join(file)).map_err(|e| format!("{}: {e}", dir.join(file).display()));
    let SketchModels { generator, vae, .. } =
        SketchModels::from_bytes(&read(terrain::models::sketch::WEIGHT_FILE)?, &read(terrain::models::sketch_vae::WEIGHT_FILE)?).map_err(|e| format!("{}: {e}", dir.display()))?;
    std::fs::create_dir_all(out_dir).map_err(|e| format!("cannot create {}: {e}", out_dir.display()))?;
    let threads = terrain::models::cpu::default_threads();
    let t = std::time::Instant::now();
    let variants = vae.variants(&sk, n, seed, &mut Default::default(), threads);
    let mut scratch = Default::default();
    let dems: Vec<Vec<f32>> = variants.iter().map(|v| generator.generate_views(v, terrain::models::sketch::FORMAT_EXTENT_M, views, &mut scratch, threads)).collect();
    let ms = t.elapsed().as_secs_f64() * 1e3;
    for (k, (v, h)) in variants.iter().zip(&dems).enumerate() {
        let write = |name: String, f: &dyn Fn(std::io::BufWriter<std::fs::File>) -> Result<(), terrain::sketch::SketchError>| -> Result<(), String> {
            let p = out_dir.join(name);
            let file = std::fs::File::create(&p).map_err(|e| format!("cannot create {}: {e}", p.display()))?;
            f(std::io::BufWriter::new(file)).map_err(|e| format!("cannot write {}: {e}", p.display()))
        };
        write(format!("variant_{k}_sketch.png"), &|w| v.write_png(w))?;
        write(format!("variant_{k}_dem.png"), &|w| write_dem_png16(w, SKETCH_PX, h))?;
    }
    eprintln!("wrote {n} variants (sketch + 16-bit terrain) to {} in {ms:.0} ms", out_dir.display());
    Ok(())
}

#[cfg(feature = "train")]
#[allow(clippy::too_many_arguments)]
pub(crate) fn train_sketch_vae(
    dems: &[terrain::train::pairs::Dem],
    steps: usize,
    resume: bool,
    checkpoint: &std::path::Path,
    every: usize,
    cfg: terrain::train::sketch_vae::VaeConfig,
    validation: usize,
    device: &burn::tensor::Device,
    budget: &mut terrain::train::Budget,
    backend: terrain::train::Backend,
) -> Result<(), String> {
    use terrain::train::{pairs, sketch, sketch_vae};
    let t = std::time::Instant::now();
    let mut run = sketch_vae::VaeRun::start(cfg, dems, device, resume.then_some(checkpoint))?;
    let val = sketch::pairs(dems, pairs::Split::Validation, validation, &sketch::WindowChoice::ALL, 0x5EED);
    eprintln!(
        "sketch VAE: {} parameters; {:?}; from step {}; pool and {} validation sketches made in {:.1} s",
        run.m.parameters(),
        run.cfg,
        run.progress.step,
        val.len(),
        t.elapsed().as_secs_f64()
    );
    let end = run.progress.step + steps;
    let mut rate = StepRate::new(run.progress.step);
    let mut last = None;
    while run.progress.step < end && !budget.spent() {
        run.step(dems)?;
        let p = &run.progress;
        rate.after_step(p.step, p.seconds);
        if p.step % 10 == 0 || p.step == end {
            eprintln!("step {:6}  reconstruction {:.4} KL {:.5} per pixel {:.2} s/step", p.step, p.l1, p.adv, p.seconds / p.step as f64);
        }
        if p.step % every == 0 || p.step == end || budget.checkpoint_due() {
            let v = sketch_vae::validate(&run.cpu()?, &val);
            eprintln!(
                "validation ({} held-out sketches): bands kept {:.3}, ridge F1 {:.3}, valley F1 {:.3}; variants change {:.3} of the bands",
                v.sketches, v.band_agreement, v.ridge_f1, v.valley_f1, v.variant_band_change
            );
            run.save(checkpoint, Some(&v))?;
            last = Some(v);
        }
    }
    let p = &run.progress;
    println!(
        "{}",
        serde_json::json!({ "steps": p.step, "seconds": p.seconds, "reconstruction": p.l1, "kl": p.adv, "validation": last, "checkpoint": checkpoint, "backend": backend, "examples_per_s": rate.examples_per_s(p.step, p.seconds, run.cfg.batch) })
    );
    Ok(())
}

pub(crate) fn sketch_extract(dem: &std::path::Path, window: &[u32], out: &std::path::Path, dem_out: Option<PathBuf>) -> Result<(), String> {
    use terrain::dem::{Heightfield, PngScale};
    use terrain::sketch::{SKETCH_PX, extract, write_dem_png16};
    let [x0, y0, side] = <[u32; 3]>::try_from(window).map_err(|_| "--window takes X0 Y0 SIDE".to_string())?;
    let (x0, y0, side) = (x0 as usize, y0 as usize, side as usize);
    let hf = Heightfield::read_path(dem, Some(1.0), PngScale::default()).map_err(|e| format!("{}: {e}", dem.display()))?;
    if side < 16 || x0 + side > hf.width || y0 + side > hf.height {
        return Err(format!("the window {x0} {y0} {side} must be at least 16 samples and lie inside the {}×{} DEM", hf.width, hf.height));
    }
    let win = hf.window(x0, y0, side, side);
    if win.data.iter().any(|v| !v.is_finite()) {
        return Err("the window has no-data samples".into());
    }
    // Bring the window to 256²: bilinear sampling at pixel centres.
    let f = side as f32 / SKETCH_PX as f32;
    let at = |x: usize, y: usize| win.data[y.min(side - 1) * side + x.min(side - 1)];
    let heights: Vec<f32> = (0..SKETCH_PX * SKETCH_PX)
        .map(|p| {
            let (sx, sy) = ((((p % SKETCH_PX) as f32 + 0.5) * f - 0.5).max(0.0), (((p / SKETCH_PX) as f32 + 0.5) * f - 0.5).max(0.0));
            let (ix, iy) = (sx as usize, sy as usize);
            let (fx, fy) = (sx - ix as f32, sy - iy as f32);
            let top = at(ix, iy) * (1.0 - fx) + at(ix + 1, iy) * fx;
            let bottom = at(ix, iy + 1) * (1.0 - fx) + at(ix + 1, iy + 1) * fx;
            top * (1.0 - fy) + bottom * fy
        })
        .collect();
    let e = extract::extract(&heights).ok_or("the window is flat")?;
    let file = std::fs::File::create(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    e.sketch.write_png(std::io::BufWriter::new(file)).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    if let Some(p) = dem_out {
        let file = std::fs::File::create(&p).map_err(|e| format!("cannot create {}: {e}", p.display()))?;
        write_dem_png16(std::io::BufWriter::new(file), SKETCH_PX, &e.target).map_err(|e| format!("cannot write {}: {e}", p.display()))?;
    }
    let (r, v) = e.sketch.stroke_cover();
    eprintln!("wrote {}: ridges cover {:.1} %, valleys {:.1} %", out.display(), r * 100.0, v * 100.0);
    Ok(())
}

pub(crate) fn eval_sketch(dir: &std::path::Path, weights: Option<PathBuf>, views: usize, variants: usize, extent_m: f64) -> Result<(), String> {
    use terrain::sketch::{self, baseline, extract, score, tidy};
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png")))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(format!("no .png pairs in {}", dir.display()));
    }
    let vae = if variants > 0 {
        let path = weights_dir(weights.clone()).join(terrain::models::sketch_vae::WEIGHT_FILE);
        let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        Some(terrain::models::sketch_vae::SketchVaeCpu::from_burnpack(&bytes).map_err(|e| format!("{}: {e}", path.display()))?)
    } else {
        None
    };
    let generator = sketch_generator(weights)?;
    let mut scratch = Default::default();
    let threads = terrain::models::cpu::default_threads();
    let mut rows = Vec::new();
    // Per pair (its row's "variants"): the sketch's own terrain's (largest, p99) neighbour
    // step and band islands, then the same for its variants as made and tidied (largest over
    // the variants, mean p99, islands summed).
    const ISLAND_PX: usize = 20;
    let v_px = terrain::sketch::SKETCH_PX * terrain::sketch::SKETCH_PX;
    let mut ms = Vec::new();
    println!("{:36} {:>8} {:>8} {:>9} {:>9} {:>6} {:>8} {:>9}", "pair", "RMSE", "PSNR", "base RMSE", "base PSNR", "bands", "ridge F1", "valley F1");
    for f in &files {
        let file = std::fs::File::open(f).map_err(|e| format!("{}: {e}", f.display()))?;
        let (sk, target) = sketch::read_pair(std::io::BufReader::new(file)).map_err(|e| format!("{}: {e}", f.display()))?;
        let base = baseline::interpolate(&sk);
        let rmse = score::rmse(&base, &target);
        let t = std::time::Instant::now();
        let ours = generator.generate_views(&sk, extent_m, views, &mut scratch, threads);
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        let e = score::rmse(&ours, &target);
        let measured = if let Some(vae) = &vae {
            let mut vs = Default::default();
            let made = vae.untidied_variants(&sk, variants, 1, &mut vs, threads);
            let tidied: Vec<sketch::Sketch> = made.iter().map(|v| tidy::tidy(v, &[&sk])).collect();
            let mut measure = |set: &[sketch::Sketch]| {
                let steps: Vec<(f32, f32)> =
                    set.iter().map(|v| score::neighbour_steps(&generator.generate_views(v, extent_m, views, &mut scratch, threads), sketch::SKETCH_PX)).collect();
                let islands: usize = set.iter().map(|v| tidy::band_islands(v, ISLAND_PX)).sum();
                let changed = set.iter().map(|v| v.band.iter().zip(&sk.band).filter(|(a, b)| a != b).count()).sum::<usize>() as f64 / (set.len() * v_px) as f64;
                serde_json::json!({ "max_step": steps.iter().map(|s| s.0).fold(0.0, f32::max), "p99_step": steps.iter().map(|s| s.1 as f64).sum::<f64>() / steps.len() as f64, "islands_under_20px": islands, "band_changed_fraction": changed })
            };
            let (own_max, own_p99) = score::neighbour_steps(&ours, sketch::SKETCH_PX);
            let own = serde_json::json!({ "max_step": own_max, "p99_step": own_p99, "islands_under_20px": tidy::band_islands(&sk, ISLAND_PX), "band_changed_fraction": 0.0 });
            Some(serde_json::json!({ "own": own, "made": measure(&made), "tidied": measure(&tidied) }))
        } else {
            None
        };
        let ex = extract::extract(&target).ok_or_else(|| format!("{}: flat DEM half", f.display()))?;
        let ag = score::Agreement::between(&ex.sketch, &sk);
        let name = f.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
        println!("{name:36} {e:8.3} {:8.2} {rmse:9.3} {:9.2} {:6.3} {:8.3} {:9.3}", score::psnr(e), score::psnr(rmse), ag.band, ag.ridge_f1(), ag.valley_f1());
        let by_scale = |h: &[f32]| score::ERROR_SCALES_PX.map(|s| score::rmse_at_scale(h, &target, s));
        let by_band = |h: &[f32]| score::rmse_by_band(h, &target, &sk.band);
        rows.push(serde_json::json!({ "pair": name, "rmse": e, "psnr": score::psnr(e), "rmse_baseline": rmse, "psnr_baseline": score::psnr(rmse),
            "rmse_by_scale": by_scale(&ours), "rmse_by_scale_baseline": by_scale(&base), "rmse_by_band": by_band(&ours), "rmse_by_band_baseline": by_band(&base), "extractor": {
            "band_agreement": ag.band, "ridge_precision": ag.ridge_precision, "ridge_recall": ag.ridge_recall, "valley_precision": ag.valley_precision, "valley_recall": ag.valley_recall } }));
        if let Some(v) = measured {
            rows.last_mut().expect("just pushed")["variants"] = v;
        }
    }
    let mean = |k: &str| rows.iter().map(|r| r[k].as_f64().unwrap_or(f64::NAN)).sum::<f64>() / rows.len() as f64;
    let mean_ex = |k: &str| rows.iter().map(|r| r["extractor"][k].as_f64().unwrap_or(f64::NAN)).sum::<f64>() / rows.len() as f64;
    let f1 = |p: f64, r: f64| 2.0 * p * r / (p + r).max(1e-12);
    println!(
        "{:36} {:8.3} {:8.2} {:9.3} {:9.2} {:6.3} {:8.3} {:9.3}",
        "mean",
        mean("rmse"),
        mean("psnr"),
        mean("rmse_baseline"),
        mean("psnr_baseline"),
        mean_ex("band_agreement"),
        f1(mean_ex("ridge_precision"), mean_ex("ridge_recall")),
        f1(mean_ex("valley_precision"), mean_ex("valley_recall"))
    );
    // Mean error by scale and by band (a band's mean over the pairs that have it).
    let mean_of = |key: &str, k: usize| {
        let v: Vec<f64> = rows.iter().filter_map(|r| r[key][k].as_f64()).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let scales: Vec<String> = score::ERROR_SCALES_PX.iter().map(|s| format!("σ {s:>2} px")).collect();
    println!("error by scale (RMSE of the difference smoothed by a Gaussian of σ): {}", scales.join("  "));
    for (what, key) in [("generator", "rmse_by_scale"), ("baseline", "rmse_by_scale_baseline")] {
        println!("  {what:10} {}", (0..scales.len()).map(|k| format!("{:8.3}", mean_of(key, k))).collect::<Vec<_>>().join(" "));
    }
    println!("error by band (RMSE over each band's pixels): band 0 .. 3");
    for (what, key) in [("generator", "rmse_by_band"), ("baseline", "rmse_by_band_baseline")] {
        println!("  {what:10} {}", (0..sketch::BANDS).map(|k| format!("{:8.3}", mean_of(key, k))).collect::<Vec<_>>().join(" "));
    }
    let by_scale_json = serde_json::json!({ "sigma_px": score::ERROR_SCALES_PX, "generator": (0..scales.len()).map(|k| mean_of("rmse_by_scale", k)).collect::<Vec<_>>(), "baseline": (0..scales.len()).map(|k| mean_of("rmse_by_scale_baseline", k)).collect::<Vec<_>>() });
    let by_band_json = serde_json::json!({ "generator": (0..sketch::BANDS).map(|k| mean_of("rmse_by_band", k)).collect::<Vec<_>>(), "baseline": (0..sketch::BANDS).map(|k| mean_of("rmse_by_band_baseline", k)).collect::<Vec<_>>() });
    ms.sort_by(f64::total_cmp);
    let variant_rows: Vec<&serde_json::Value> = rows.iter().filter_map(|r| r.get("variants")).collect();
    if !variant_rows.is_empty() {
        println!(
            "variants ({variants} a sketch, seed 1): neighbour step of the terrain (0–255), largest / mean p99; band islands under {ISLAND_PX} px; pixels whose band differs from the sketch's"
        );
        for (k, name) in ["own", "made", "tidied"].iter().enumerate() {
            let largest = variant_rows.iter().map(|r| r[name]["max_step"].as_f64().unwrap_or(f64::NAN)).fold(0.0, f64::max);
            let p99 = variant_rows.iter().map(|r| r[name]["p99_step"].as_f64().unwrap_or(f64::NAN)).sum::<f64>() / variant_rows.len() as f64;
            let islands: u64 = variant_rows.iter().map(|r| r[name]["islands_under_20px"].as_u64().unwrap_or(0)).sum();
            let changed = variant_rows.iter().map(|r| r[name]["band_changed_fraction"].as_f64().unwrap_or(f64::NAN)).sum::<f64>() / variant_rows.len() as f64;
            let what = ["the sketches' own terrain", "variants as the VAE's edit makes them", "variants tidied (as the page and CLI give them)"][k];
            println!("  {what:48} largest {largest:6.2}  p99 {p99:5.2}  islands {islands:4}  changed {:5.1} %", 100.0 * changed);
        }
    }
    println!(
        "{}",
        serde_json::json!({ "pairs": rows.len(), "mean": { "rmse": mean("rmse"), "psnr": mean("psnr"), "rmse_baseline": mean("rmse_baseline"), "psnr_baseline": mean("psnr_baseline"),
        "extractor_band_agreement": mean_ex("band_agreement"), "extractor_ridge_precision": mean_ex("ridge_precision"), "extractor_ridge_recall": mean_ex("ridge_recall"),
        "extractor_valley_precision": mean_ex("valley_precision"), "extractor_valley_recall": mean_ex("valley_recall") }, "rmse_by_scale": by_scale_json, "rmse_by_band": by_band_json, "extent_m": extent_m, "views": views, "generator_ms_median": ms[ms.len() / 2], "per_pair": rows })
    );
    Ok(())
}
