//! `terrain world`, `eval-tcm` and `train-tcm`: the learned world from the command line.

#[allow(unused_imports)]
use crate::*;

/// The tile rectangle of `--tiles X0 Y0 W H`, checked without overflow: W, H ≥ 1, W·H ≤
/// [`MAX_EXPORT_TILES`], every coordinate within ±2³⁰.
pub(crate) fn tile_rect(t: &[i64]) -> Result<(i32, i32, u32, u32), String> {
    let [x0, y0, w, h] = <[i64; 4]>::try_from(t).map_err(|_| "--tiles takes X0 Y0 W H".to_string())?;
    if w < 1 || h < 1 || (w as i128) * (h as i128) > MAX_EXPORT_TILES as i128 {
        return Err(format!("W×H must be between 1 and {MAX_EXPORT_TILES} tiles, got {w}×{h}"));
    }
    let limit = 1i64 << 30;
    if [x0, y0, x0.saturating_add(w), y0.saturating_add(h)].iter().any(|v| v.abs() > limit) {
        return Err(format!("tile coordinates must stay within ±{limit}"));
    }
    Ok((x0 as i32, y0 as i32, w as u32, h as u32))
}

/// The pins of `--pin FILE@I,J[,M]` arguments ([`terrain::world::pins::Pins::add`]).
pub(crate) fn read_pins(args: &[String]) -> Result<terrain::world::pins::Pins, String> {
    let mut pins = terrain::world::pins::Pins::new();
    for a in args {
        let (file, at) = a.rsplit_once('@').ok_or_else(|| format!("--pin takes FILE@I,J[,SPACING_M], not '{a}'"))?;
        let parts: Vec<&str> = at.split(',').map(str::trim).collect();
        let bad = || format!("--pin {a}: after @ come the tile I,J (whole numbers) and, for a file without its own pixel size, its spacing in metres; not '{at}'");
        let (i, j, spacing) = match parts[..] {
            [i, j] => (i.parse::<i32>().map_err(|_| bad())?, j.parse::<i32>().map_err(|_| bad())?, None),
            [i, j, s] => {
                (i.parse::<i32>().map_err(|_| bad())?, j.parse::<i32>().map_err(|_| bad())?, Some(s.parse::<f64>().ok().filter(|s| s.is_finite() && *s > 0.0).ok_or_else(bad)?))
            }
            _ => return Err(bad()),
        };
        let limit = 1 << 30;
        if i.abs() > limit || j.abs() > limit {
            return Err(format!("--pin {a}: tile coordinates must stay within ±{limit}"));
        }
        let hf = terrain::dem::Heightfield::read_user_path(std::path::Path::new(file), spacing, terrain::dem::PngScale::default()).map_err(|e| format!("--pin {file}: {e}"))?;
        let added = pins.add(&hf, terrain::grid::TileCoord::new(i, j)).map_err(|e| format!("--pin {file}: {e}"))?;
        let n = added.tiles.len();
        eprintln!("pinned {file}: {n} tile{} from ({i}, {j}){}", if n == 1 { "" } else { "s" }, added.detail_said());
    }
    Ok(pins)
}

/// `terrain world`: the tiles are made by the same runner and requests as the page's CPU
/// worker (a [`NativeRunner`] thread), so the CLI, the tests and the page run one code path.
///
/// [`NativeRunner`]: terrain::jobs::native::NativeRunner
pub(crate) fn world(r: &RegionArgs) -> Result<(), String> {
    terrain::dem::formats::Format::of(&r.out).map_err(|e| e.to_string())?;
    let (hf, ..) = region(r)?;
    write_heights(hf, &r.out, r.pow2_plus_1)
}

/// `terrain export`: the region of [`world`] at `spacing_m`: the 32 m tiles, or refined by the
/// TEM as `terrain enhance` refines a DEM; `format`, when given, must agree with the --out
/// file's extension.
pub(crate) fn export(r: &RegionArgs, spacing_m: f64, format: Option<ExportFormat>) -> Result<(), String> {
    terrain::dem::formats::Format::of(&r.out).map_err(|e| e.to_string())?;
    if let Some(f) = format {
        format_agrees(&r.out, f)?;
    }
    let base = terrain::grid::BASE_SPACING_M;
    // The TEM levels from 32 m down to the spacing (none at 32 m), checked before any work.
    let levels = (spacing_m != base)
        .then(|| terrain::enhance::levels_for(base, spacing_m))
        .transpose()
        .map_err(|_| format!("--spacing must be 32, 16, 8, 4, 2 or 1 metres, not {spacing_m}"))?;
    let (hf, pins, origin) = region(r)?;
    let hf = match levels {
        None => hf,
        Some((first, last)) => {
            terrain::enhance::output_size(hf.width, hf.height, last - first + 1).map_err(|e| e.to_string())?;
            let tem = terrain::models::tem::TemSet::load_dir(&weights_dir(r.weights.clone()), &terrain::models::tem::Exec::cpu())?;
            let t = std::time::Instant::now();
            let (refined, stats) = terrain::enhance::enhance_pinned(&hf, base, spacing_m, &tem, 4, &pins, origin, &mut |_, _, _| {}).map_err(|e| e.to_string())?;
            eprintln!(
                "refined {}×{} at 32 m to {}×{} at {spacing_m} m: {} patches in {:.1} s",
                hf.width,
                hf.height,
                refined.width,
                refined.height,
                stats.quads_made,
                t.elapsed().as_secs_f64()
            );
            refined
        }
    };
    write_heights(hf, &r.out, r.pow2_plus_1)
}

/// Whether `out`'s extension is the file `format` writes (an error says which it should be).
pub(crate) fn format_agrees(out: &std::path::Path, format: ExportFormat) -> Result<(), String> {
    use terrain::dem::formats::Format;
    let of_file = Format::of(out).map_err(|e| e.to_string())?;
    let (want, name, ext) = match format {
        ExportFormat::Png16 => (Format::Png16, "png16", ".png"),
        ExportFormat::Raw => (Format::Raw16, "raw", ".raw"),
        ExportFormat::Tif => (Format::GeoTiff, "tif", ".tif"),
        ExportFormat::Glb => (Format::Glb, "glb", ".glb"),
    };
    if want != of_file {
        return Err(format!("--format {name} writes a {ext} file; --out {} is another format", out.display()));
    }
    Ok(())
}

/// Why `relief_m` is not a sketch's relief (`--relief`), if it is not.
pub(crate) fn check_relief(relief_m: f64) -> Result<(), String> {
    let range = terrain::world::sketched::RELIEF_M;
    if !range.contains(&relief_m) {
        return Err(format!("--relief must be between {} and {} metres, not {relief_m}", range.start(), range.end()));
    }
    Ok(())
}

/// The 32 m heights of `r`'s tiles, made by the page's worker procedure (with its pins and
/// sketch), the pins, and the region's first tile (its north-west sample is the heights' first).
fn region(r: &RegionArgs) -> Result<(terrain::dem::Heightfield, terrain::world::pins::Pins, terrain::grid::TileCoord), String> {
    use terrain::grid::TileCoord;
    use terrain::jobs::protocol::{Envelope, Reply, Request};
    let (x0, y0, w, h) = tile_rect(&r.tiles)?;
    let (source, weights) = (r.source, r.weights.clone());
    let sketch = r.sketch.as_deref().map(|s| (s, r.relief, r.extent_m));
    if (!r.pin.is_empty() || sketch.is_some()) && source != Source::Tcm {
        return Err("--pin and --sketch grow the learned world around your terrain: add --source tcm".into());
    }
    let mut pins = read_pins(&r.pin)?;
    let runner = terrain::jobs::native::NativeRunner::spawn(terrain::models::cpu::default_threads());
    let ask = |request| -> Result<Reply, String> {
        let answer = runner.call(&Envelope { id: 1, epoch: 0, rest_per_work: 0.0, request }).map_err(|e| e.to_string())?;
        match answer.reply {
            Reply::Failed(why) => Err(why),
            r => Ok(r),
        }
    };
    let noise = match source {
        Source::Procedural => Some(NoiseParams::default()),
        Source::Tcm => {
            use terrain::world::learned::{GROW_FILE, TCM_FILE};
            let dir = weights_dir(weights.clone());
            let read = |f: &str| terrain::models::read_weight_file(&dir.join(f)).map_err(|e| e.to_string());
            ask(Request::LoadWorld { tcm: read(TCM_FILE)?, grow: read(GROW_FILE)? })?;
            if let Some((file, relief_m, extent_m)) = sketch {
                use terrain::world::sketched::SketchSource;
                check_relief(relief_m)?;
                let sk = terrain::sketch::Sketch::read_path(file).map_err(|e| format!("--sketch {}: {e}", file.display()))?;
                let heights = sketch_generator(weights.clone())?.exact().generate(&sk, extent_m, &mut Default::default(), terrain::models::cpu::default_threads());
                let mut source = SketchSource::with_extent(std::sync::Arc::new(heights), relief_m, extent_m, r.seed);
                if source.takes_base() {
                    // Set into the learned world's own tile (0, 0), as the page does.
                    match ask(Request::UnpinnedTile { seed: r.seed, tile: TileCoord::new(0, 0) })? {
                        Reply::Heights { heights, .. } => source = source.with_base(std::sync::Arc::new(heights)),
                        other => return Err(format!("the ground for the sketch: unexpected reply {other:?}")),
                    }
                }
                let sketched = source.pins();
                // With its own detail where it is finer than 32 m (`export --spacing` keeps it).
                for (c, tile) in sketched.iter() {
                    pins.insert_tile(c, tile.clone())?;
                }
                let tiles: Vec<String> = sketched.coords().iter().map(|c| format!("({}, {})", c.i, c.j)).collect();
                let set = if source.soft_edge().is_some() { ", set into the learned world's own tile" } else { "" };
                eprintln!("pinned the sketch {} ({relief_m} m relief, {extent_m} m across) on tile(s) {}{set}", file.display(), tiles.join(", "));
            }
            if !pins.is_empty() {
                ask(Request::pin(&pins))?;
            }
            None
        }
    };
    let mut made = std::collections::HashMap::new();
    for j in y0..y0 + h as i32 {
        for i in x0..x0 + w as i32 {
            let tile = TileCoord::new(i, j);
            match ask(Request::Tile { seed: r.seed, tile, noise })? {
                Reply::Heights { heights, .. } => made.insert(tile, std::sync::Arc::new(terrain::world::Tile::new(tile, heights))),
                other => return Err(format!("tile {i}, {j}: unexpected reply {other:?}")),
            };
        }
    }
    Ok((export::from_tiles(x0, y0, w, h, |c| made.get(&c).cloned()).ok_or("a tile was not made")?, pins, TileCoord::new(x0, y0)))
}

/// Writes `hf` to `out` in the format of its extension (resampled to 2ⁿ+1 when asked) and
/// says what was written.
pub(crate) fn write_heights(hf: terrain::dem::Heightfield, out: &std::path::Path, pow2_plus_1: bool) -> Result<(), String> {
    let hf = if pow2_plus_1 { hf.to_pow2_plus_1() } else { hf };
    let sidecar = hf.export_path(out).map_err(|e| save_error(out, e))?;
    match sidecar {
        Some(s) => eprintln!("wrote {} ({}×{} samples at {:.3} m; 0 = {:.2} m, 65535 = {:.2} m) and its .json", out.display(), s.width, s.height, s.spacing_m, s.min_m, s.max_m),
        None => eprintln!("wrote {}: {}×{} samples at {} m", out.display(), hf.width, hf.height, hf.spacing_m),
    }
    Ok(())
}

/// What to say when `out` could not be saved: the file could not be created or written (I/O),
/// or the grid cannot be written in its format.
pub(crate) fn save_error(out: &std::path::Path, e: terrain::dem::DemError) -> String {
    match e {
        terrain::dem::DemError::Io(io) => format!("cannot create {}: {io}", out.display()),
        e => format!("cannot write {}: {e}", out.display()),
    }
}

/// What `train-tcm` trains the TCM on.
#[cfg(feature = "train")]
pub(crate) enum TcmData<'a> {
    /// The DEMs of a folder with its manifest, area-averaged to 128 m (and 32 m for the ×4 step).
    Dems(&'a std::path::Path),
    /// The Web Mercator grids of a folder ([`mercator_data`]) at a spacing (metres).
    Mercator(&'a std::path::Path, f64),
}

#[cfg(feature = "train")]
#[allow(clippy::too_many_arguments)]
pub(crate) fn train_tcm(
    data: TcmData,
    steps: usize,
    resume: bool,
    checkpoint: &std::path::Path,
    every: usize,
    [batch, macro_cells]: [usize; 2],
    [adversarial, ruggedness, drainage, coarse, free_l1, l1_reach, dome, coherence]: [f32; 8],
    [joined, disc_slopes]: [bool; 2],
    [position, grow_position]: [Option<f32>; 2],
    init: Option<&std::path::Path>,
    [tcm_only, grow_only, snapshots]: [bool; 3],
    run_args: &RunArgs,
) -> Result<(), String> {
    use terrain::train::{grow, tcm};
    for (flag, w) in [
        ("--adversarial", adversarial),
        ("--ruggedness", ruggedness),
        ("--drainage", drainage),
        ("--coarse", coarse),
        ("--free-l1", free_l1),
        ("--l1-reach", l1_reach),
        ("--dome", dome),
        ("--coherence", coherence),
        ("--position", position.unwrap_or(0.0)),
        ("--grow-position", grow_position.unwrap_or(0.0)),
    ] {
        if !w.is_finite() || w < 0.0 {
            return Err(format!("{flag} must be a finite number ≥ 0, not {w}"));
        }
    }
    if !tcm::valid_macro_cells(macro_cells) {
        return Err(format!("--macro-cells must be a multiple of 3 that divides {}, not {macro_cells}", terrain::models::tcm::CONTEXT_PX));
    }
    let (grids, fine) = match data {
        TcmData::Mercator(dir, spacing) => (mercator_data(dir, spacing)?, Vec::new()),
        TcmData::Dems(dir) => tcm_data(dir)?,
    };
    let (device, mut budget) = run_args.start()?;
    let cfg = tcm::TcmConfig {
        batch,
        macro_cells,
        adversarial,
        ruggedness,
        drainage,
        coarse,
        free_l1,
        l1_reach_px: l1_reach,
        joined,
        dome,
        disc_slopes,
        position: position.unwrap_or(0.0),
        coherence,
        ..Default::default()
    };
    let (run, mut up) = start_tcm_runs(cfg, position, &device, resume.then_some(checkpoint), init, [tcm_only, grow_only])?;
    if let Some(w) = grow_position {
        up.position = w;
    }
    let mut run = run;
    eprintln!("TCM: {} parameters, ×4: {} parameters; {:?}; from step {}", run.g.parameters(), up.parameters(), run.cfg, run.progress.step);
    // The step count of the part being trained.
    let at = |run: &tcm::TcmRun, up: &grow::GrowRun| if grow_only { up.progress.step } else { run.progress.step };
    let end = at(&run, &up) + steps;
    let (mut tcm_rate, mut grow_rate) = (StepRate::new(run.progress.step), StepRate::new(up.progress.step));
    while at(&run, &up) < end && !budget.spent() {
        if !grow_only {
            run.step(&grids)?;
        }
        if !tcm_only {
            up.step(&fine, run.cfg.seed)?;
        }
        let (p, q) = (&run.progress, &up.progress);
        tcm_rate.after_step(p.step, p.seconds);
        grow_rate.after_step(q.step, q.seconds);
        let step = at(&run, &up);
        if step % 10 == 0 || step == end {
            eprintln!(
                "step {:6}  TCM l1 {:.4} adv {:.3} disc {:.3} pits {:.5} {:.2} s/step | ×4 l1 {:.4} adv {:.3} disc {:.3} {:.2} s/step",
                step,
                p.l1,
                p.adv,
                p.disc,
                p.depression,
                p.seconds / p.step.max(1) as f64,
                q.l1,
                q.adv,
                q.disc,
                q.seconds / q.step.max(1) as f64
            );
        }
        if step % every == 0 || step == end || budget.checkpoint_due() {
            if !grow_only {
                run.save(checkpoint)?;
                if snapshots {
                    // Each checkpoint's generator kept, to pick one by eval-tcm afterwards.
                    super::keep_snapshot(checkpoint, tcm::GEN_FILE, "tcm", run.progress.step)?;
                }
            }
            if !tcm_only {
                up.save(checkpoint)?;
            }
        }
    }
    let summary = |p: &tcm::TcmProgress, rate: &StepRate, batch: usize| serde_json::json!({ "steps": p.step, "seconds": p.seconds, "l1": p.l1, "adv": p.adv, "disc": p.disc, "examples_per_s": rate.examples_per_s(p.step, p.seconds, batch) });
    println!(
        "{}",
        serde_json::json!({ "tcm": summary(&run.progress, &tcm_rate, run.cfg.batch), "grow": summary(&up.progress, &grow_rate, up.batch), "checkpoint": checkpoint, "backend": run_args.backend })
    );
    Ok(())
}

/// The TCM's 128 m grids and the ×4 step's 32 m grids of the DEMs in `dem_dir`, with what
/// they hold reported on stderr (the DEMs, the real tiles' level statistics, ruggedness by
/// split).
#[cfg(feature = "train")]
fn tcm_data(dem_dir: &std::path::Path) -> Result<(Vec<terrain::train::pairs::Grid>, Vec<terrain::train::pairs::Grid>), String> {
    use terrain::train::{grow, pairs, tcm};
    let dems = pairs::load_dems(dem_dir)?;
    let grids = tcm::grids(&dems);
    let fine = grow::grids(&dems);
    let names = |v: Vec<&str>| v.join(", ");
    if grids.is_empty() || fine.is_empty() {
        return Err(format!(
            "{} needs DEMs with room for a 3×3-tile window at 128 m ({} found) and for a 224² window at 32 m or finer ({} found) in both splits",
            dem_dir.display(),
            grids.len(),
            fine.len()
        ));
    }
    eprintln!("TCM data, {} DEMs at 128 m: {}", grids.len(), names(grids.iter().map(|g| g.id.as_str()).collect()));
    let (level, level_sd, step) = tcm::tile_mean_stats(&grids);
    eprintln!("real 4 km tile means: level {level:.0} ± {level_sd:.0} m, rms step between neighbours {step:.0} m");
    eprintln!("×4 data, {} DEMs at 32 m: {}", fine.len(), names(fine.iter().map(|g| g.id.as_str()).collect()));
    let fine_ids: Vec<&str> = fine.iter().map(|g| g.id.as_str()).collect();
    let all: Vec<&pairs::Grid> = grids.iter().collect();
    let (fine_coarse, rest): (Vec<_>, Vec<_>) = grids.iter().partition(|g| fine_ids.contains(&g.id.as_str()));
    for (what, set) in [("all", &all), ("32 m or finer", &fine_coarse), ("coarser", &rest)] {
        report_ruggedness(&format!("{what} DEMs"), set);
    }
    Ok((grids, fine))
}

/// Prints the ruggedness statistics ([`terrain::train::tcm::ruggedness_stats`]) of `set`, named
/// `what`, in both splits.
#[cfg(feature = "train")]
fn report_ruggedness(what: &str, set: &[&terrain::train::pairs::Grid]) {
    use terrain::train::{pairs, tcm};
    for split in [pairs::Split::Train, pairs::Split::Validation] {
        if let Some((m, sd, p95)) = tcm::ruggedness_stats(set, split) {
            eprintln!("ruggedness of {what} ({split:?}): {m:.2} ± {sd:.2}, 95th percentile {p95:.2}");
        }
    }
}

/// The TCM's data for a coarse level: the Web Mercator grids of `dir` in bands of 256 rows
/// ([`terrain::train::pairs::load_mercator_bands`]) area-averaged to `spacing_m`, those with
/// room for a 3×3-tile window in both splits.
#[cfg(feature = "train")]
fn mercator_data(dir: &std::path::Path, spacing_m: f64) -> Result<Vec<terrain::train::pairs::Grid>, String> {
    use terrain::models::tcm::CONTEXT_PX;
    use terrain::train::pairs;
    if !(spacing_m.is_finite() && spacing_m > 0.0) {
        return Err(format!("--spacing-m must be a positive number of metres, not {spacing_m}"));
    }
    let bands = pairs::load_mercator_bands(dir, 256)?;
    let grids = pairs::grids_at(&bands, spacing_m, CONTEXT_PX);
    if grids.is_empty() {
        return Err(format!("{} has no band at {spacing_m} m or finer with room for a {CONTEXT_PX}² window in both splits", dir.display()));
    }
    let land: usize = grids.iter().map(|g| g.hf.data.iter().filter(|v| v.is_finite()).count()).sum();
    eprintln!("TCM data, {} of {} bands at {spacing_m} m ({land} land samples): {}", grids.len(), bands.len(), grids.iter().map(|g| g.id.as_str()).collect::<Vec<_>>().join(", "));
    report_ruggedness("all bands", &grids.iter().collect::<Vec<_>>());
    Ok(grids)
}

/// The TCM run and the ×4 step's run: from the checkpoint in `from` (each part that is
/// trained; `[tcm_only, grow_only]`), else fresh or from the weights in `init`. A `position`
/// weight given replaces a resumed run's.
#[cfg(feature = "train")]
fn start_tcm_runs(
    cfg: terrain::train::tcm::TcmConfig,
    position: Option<f32>,
    device: &burn::tensor::Device,
    from: Option<&std::path::Path>,
    init: Option<&std::path::Path>,
    [tcm_only, grow_only]: [bool; 2],
) -> Result<(terrain::train::tcm::TcmRun, terrain::train::grow::GrowRun), String> {
    use terrain::train::{grow, tcm};
    let (batch, adversarial) = (cfg.batch, cfg.adversarial);
    let start = match init {
        Some(dir) => {
            let file = dir.join(tcm::GEN_FILE);
            let bytes = std::fs::read(&file).map_err(|e| format!("{}: {e}", file.display()))?;
            // Weights of today's layout as they are, else of the first layout widened.
            let g = terrain::models::tcm::TcmCpu::from_burnpack(&bytes).or_else(|_| terrain::models::tcm::TcmCpu::widened(&bytes));
            Some(g.map_err(|e| format!("{}: {e}", file.display()))?)
        }
        None => None,
    };
    // A part that is not trained needs no checkpoint: it starts fresh and is not saved.
    let mut run = tcm::start_run(cfg, device, from.filter(|_| !grow_only), start.as_ref())?;
    if let Some(w) = position {
        run.cfg.position = w;
    }
    let mut up = grow::GrowRun::start(batch, adversarial, device, from.filter(|_| !tcm_only))?;
    if let Some(dir) = init.filter(|_| !tcm_only) {
        // The shipped file holds float16 weights, which burn's loader does not convert.
        let file = dir.join(grow::GROW_FILE);
        let bytes = std::fs::read(&file).map_err(|e| format!("{}: {e}", file.display()))?;
        let g = terrain::models::grow::GrowCpu::from_burnpack(&bytes).map_err(|e| format!("{}: {e}", file.display()))?;
        up.g = g.into_model(up.g);
    }
    Ok((run, up))
}

#[cfg(feature = "train")]
pub(crate) fn eval_tcm(dem_dir: &std::path::Path, weights: &std::path::Path, seeds: u64) -> Result<(), String> {
    use std::sync::Arc;
    use terrain::geomorph::{self, STAT_NAMES};
    use terrain::train::{pairs, world_eval};
    use terrain::world::TileCoord;
    use terrain::world::learned::{LearnedModels, LearnedSource};
    let dems = pairs::load_dems(dem_dir)?;
    let models = Arc::new(LearnedModels::load_dir(weights)?);
    let learned = LearnedSource::new(models.clone(), terrain::models::cpu::default_threads());
    let procedural = ProceduralSource::new(NoiseParams::default());
    const SIDE_TILES: usize = 6;
    // The regions' north-west tile: SIDE_TILES² tiles around the origin.
    let origin = TileCoord::new(-(SIDE_TILES as i32) / 2, -(SIDE_TILES as i32) / 2);
    // Each statistic's median over a set of windows, to see which way a world is off.
    let medians = |st: &[geomorph::Stats]| -> serde_json::Map<String, serde_json::Value> {
        STAT_NAMES
            .iter()
            .enumerate()
            .map(|(k, n)| {
                let mut v: Vec<f64> = st.iter().map(|s| s.values()[k]).collect();
                v.sort_by(f64::total_cmp);
                (n.to_string(), serde_json::json!(v[v.len() / 2]))
            })
            .collect()
    };
    let mut regions: Vec<(&str, Vec<terrain::dem::Heightfield>, f64)> = Vec::new();
    for (name, src) in [("tcm", &learned as &dyn TileSource), ("procedural", &procedural as &dyn TileSource)] {
        let t0 = std::time::Instant::now();
        let r: Vec<_> = (1..=seeds).map(|s| world_eval::region(src, s, origin, SIDE_TILES, SIDE_TILES)).collect();
        let ms = t0.elapsed().as_secs_f64() * 1e3 / (seeds as usize * SIDE_TILES * SIDE_TILES) as f64;
        regions.push((name, r, ms));
    }
    // Where the learned world's time went, per world tile made (each part's runs and ms).
    let spent = learned.time_spent();
    let world_tiles = (seeds as usize * SIDE_TILES * SIDE_TILES) as f64;
    let mut time_by_part = serde_json::to_value(spent).expect("json");
    for part in time_by_part.as_object_mut().expect("an object").values_mut() {
        let ms = part["ms"].as_f64().unwrap_or(0.0);
        part["ms_per_world_tile"] = serde_json::json!(ms / world_tiles);
        part["share"] = serde_json::json!(ms / spent.total_ms().max(1e-9));
    }
    eprintln!(
        "learned world, ms per world tile by part: {}",
        time_by_part.as_object().expect("an object").iter().map(|(k, v)| format!("{k} {:.1}", v["ms_per_world_tile"].as_f64().unwrap_or(0.0))).collect::<Vec<_>>().join(", ")
    );
    let mut sides = Vec::new();
    let mut drainage = serde_json::Map::new();
    for side in world_eval::WINDOW_SIDES {
        let real = world_eval::stats_of(&world_eval::real_windows(&dems, side), side);
        if real.is_empty() {
            return Err(format!("no NaN-free {side}² validation window at 32 m or finer in {}", dem_dir.display()));
        }
        let mut worlds = serde_json::Map::new();
        let mut means = Vec::new();
        // Drainage (flat area, closed depressions at ~100 m and ~400 m, longest flow path) on
        // the larger windows only: a 4 km window is too small for ~400 m and for flow paths.
        let largest = side == world_eval::WINDOW_SIDES[world_eval::WINDOW_SIDES.len() - 1];
        let real_drainage = if largest { world_eval::drainage_of(&world_eval::real_windows(&dems, side), side) } else { Vec::new() };
        let mut with_drainage = Vec::new();
        for (name, rs, _) in &regions {
            let wins: Vec<Vec<f32>> = rs.iter().flat_map(|r| world_eval::windows_of(r, side)).collect();
            let st = world_eval::stats_of(&wins, side);
            let d = geomorph::distance(&st, &real);
            means.push(d[STAT_NAMES.len()]);
            if largest {
                let dr = world_eval::drainage_of(&wins, side);
                let dd = geomorph::drainage::distance(&dr, &real_drainage);
                let n = (STAT_NAMES.len() + geomorph::drainage::DRAINAGE_NAMES.len()) as f64;
                with_drainage.push((d[..STAT_NAMES.len()].iter().sum::<f64>() + dd[..geomorph::drainage::DRAINAGE_NAMES.len()].iter().sum::<f64>()) / n);
                drainage.insert(name.to_string(), drainage_summary(&dr, Some(&dd)));
            }
            let per: serde_json::Map<String, serde_json::Value> = STAT_NAMES.iter().zip(&d).map(|(n, v)| (n.to_string(), serde_json::json!(v))).collect();
            worlds.insert(name.to_string(), serde_json::json!({ "windows": st.len(), "distance": d[STAT_NAMES.len()], "per_statistic": per, "medians": medians(&st) }));
        }
        let mut entry =
            serde_json::json!({ "window": side, "real_windows": real.len(), "real_medians": medians(&real), "worlds": worlds, "ratio_tcm_over_procedural": means[0] / means[1] });
        if largest {
            entry["ratio_tcm_over_procedural_with_drainage"] = serde_json::json!(with_drainage[0] / with_drainage[1]);
            drainage.insert("real_validation".into(), drainage_summary(&real_drainage, None));
        }
        sides.push(entry);
    }
    // Seam figures pooled over the edges of all seeds' regions, and the same figures on
    // real terrain cut into tiles (the validation windows of 256 samples: one edge each way),
    // which has no seams: what a seamless world scores.
    let seam_figures = |fields: &[terrain::dem::Heightfield]| {
        let seam: Vec<f64> = fields.iter().flat_map(world_eval::seam_ratios).collect();
        let crease: Vec<f64> = fields.iter().flat_map(world_eval::crease_ratios).collect();
        let ((m, p), (cm, cp), (sm, sp)) = (world_eval::mean_p95(&seam), world_eval::mean_p95(&crease), world_eval::seam_steps(fields));
        serde_json::json!({ "edges": seam.len(), "seam_mean": m, "seam_p95": p, "crease_mean": cm, "crease_p95": cp, "edge_step_over_inner_step_mean": sm, "edge_step_over_inner_step_p95": sp })
    };
    let mut seams: serde_json::Map<String, serde_json::Value> = regions
        .iter()
        .map(|(name, rs, ms)| {
            let mut f = seam_figures(rs);
            let strip: Vec<f64> = rs.iter().map(world_eval::edge_strip_ratio).collect();
            f["edge_strip"] = serde_json::json!(strip.iter().sum::<f64>() / strip.len() as f64);
            let windows: Vec<Vec<f32>> = rs.iter().flat_map(|r| world_eval::windows_of(r, world_eval::WINDOW_SIDES[1])).collect();
            f["grid_alignment"] = serde_json::json!(window_mean(windows.iter().map(Vec::as_slice), world_eval::grid_alignment));
            f["orientation_coherence"] = serde_json::json!(window_mean(windows.iter().map(Vec::as_slice), world_eval::orientation_coherence));
            f["ms_per_tile"] = serde_json::json!(ms);
            (name.to_string(), f)
        })
        .collect();
    let side = world_eval::WINDOW_SIDES[1];
    let real: Vec<terrain::dem::Heightfield> =
        world_eval::real_windows(&dems, side).into_iter().map(|w| terrain::dem::Heightfield::new(side, side, terrain::grid::BASE_SPACING_M, w)).collect();
    let mut real_figures = seam_figures(&real);
    real_figures["grid_alignment"] = serde_json::json!(window_mean(real.iter().map(|r| r.data.as_slice()), world_eval::grid_alignment));
    real_figures["orientation_coherence"] = serde_json::json!(window_mean(real.iter().map(|r| r.data.as_slice()), world_eval::orientation_coherence));
    seams.insert("real_validation_cut_into_tiles".into(), real_figures);
    // The large scale: does a 24 km square drain through long valleys, do its ranges run side
    // by side? Each world's regions against every real DEM's 24 km squares.
    let large = |squares: &[Vec<f32>]| {
        let n = (world_eval::LARGE_SQUARE_M / world_eval::LARGE_SPACING_M) as usize;
        let figures: Vec<(f64, f64)> = squares.iter().map(|h| world_eval::large_scale(h, n)).collect();
        let mean = |k: fn(&(f64, f64)) -> f64| figures.iter().map(k).sum::<f64>() / figures.len().max(1) as f64;
        serde_json::json!({ "squares": figures.len(), "longest_flow_path_km": mean(|f| f.0), "orientation_coherence_512m": mean(|f| f.1) })
    };
    let mut large_scale: serde_json::Map<String, serde_json::Value> = regions
        .iter()
        .map(|(name, rs, _)| {
            let squares: Vec<Vec<f32>> = rs.iter().filter_map(|r| r.resample_area(world_eval::LARGE_SPACING_M).ok()).map(|r| r.data).collect();
            (name.to_string(), large(&squares))
        })
        .collect();
    large_scale.insert("real_both_splits".into(), large(&world_eval::real_squares(&dems)));
    // Does the TCM make tiles as rugged as the world asks? Mean and deviation over the regions.
    let mean_sd = |v: &[f64]| {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        serde_json::json!({ "mean": m, "sd": (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt() })
    };
    let (mut asked, mut made) = (Vec::new(), Vec::new());
    for s in 1..=seeds {
        for k in 0..SIDE_TILES * SIDE_TILES {
            let c = origin.offset(k as i32 % SIDE_TILES as i32, k as i32 / SIDE_TILES as i32);
            asked.push(terrain::world::learned::ruggedness(s, c) as f64);
            made.push(learned.made_ruggedness(s, c) as f64);
        }
    }
    let ruggedness = serde_json::json!({ "asked": mean_sd(&asked), "made": mean_sd(&made) });
    // Does the TCM give its tiles a shape of their own by phase (the quilt in hillshades)?
    let grids = terrain::train::tcm::grids(&dems);
    let domes = terrain::train::tcm::phase_dome_bias(&models.tcm, &grids, 400, terrain::models::cpu::default_threads());
    let domes: Vec<serde_json::Value> = domes.iter().enumerate().map(|(p, (m, e))| serde_json::json!({ "phase": p, "made_minus_real_m": m, "standard_error_m": e })).collect();
    println!("{}", serde_json::to_string_pretty(&serde_json::json!({ "weights": models.hash, "seeds": seeds, "region_tiles": [SIDE_TILES, SIDE_TILES], "realism": sides, "drainage_256_windows": drainage, "seams_and_speed": seams, "large_scale_24km": large_scale, "tcm_time_by_part": time_by_part, "ruggedness_128m_tiles": ruggedness, "tile_dome_bias_by_phase_128m_validation": domes })).expect("json"));
    Ok(())
}

/// The mean of `measure` (e.g. [`terrain::train::world_eval::grid_alignment`]) over 32 m
/// windows of side [`terrain::train::world_eval::WINDOW_SIDES`]`[1]`.
fn window_mean<'a>(windows: impl Iterator<Item = &'a [f32]>, measure: fn(&[f32], usize) -> f64) -> f64 {
    let side = terrain::train::world_eval::WINDOW_SIDES[1];
    let (sum, count) = windows.fold((0.0, 0usize), |(s, k), w| (s + measure(w, side), k + 1));
    sum / count.max(1) as f64
}

/// Per drainage statistic, the mean and median over `set` (and its distance to the real
/// windows, when given).
fn drainage_summary(set: &[terrain::geomorph::drainage::Drainage], distance: Option<&[f64]>) -> serde_json::Value {
    use terrain::geomorph::drainage::DRAINAGE_NAMES;
    let per: serde_json::Map<String, serde_json::Value> = DRAINAGE_NAMES
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let mut v: Vec<f64> = set.iter().map(|d| d.values()[k]).collect();
            v.sort_by(f64::total_cmp);
            let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
            let mut e = serde_json::json!({ "mean": mean, "median": v.get(v.len() / 2) });
            if let Some(d) = distance {
                e["distance"] = serde_json::json!(d[k]);
            }
            (n.to_string(), e)
        })
        .collect();
    serde_json::json!({ "windows": set.len(), "statistics": per })
}

/// `terrain range-field`: the range field of world `seed` over the `side`² samples centred on
/// the origin, written to `out` as a float32 GeoTIFF at 1,024 m.
pub(crate) fn range_field(seed: u64, side: usize, out: &std::path::Path) -> Result<(), String> {
    use terrain::world::ranges;
    if out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() != Some("tif") {
        return Err(format!("{}: the range field is written as a .tif", out.display()));
    }
    let half = side as i64 / 2;
    let field = ranges::RangeField::default().samples(seed, -half, -half, side, side);
    let hf = terrain::dem::Heightfield::new(side, side, ranges::RANGE_SPACING_M, field);
    let file = std::fs::File::create(out).map_err(|e| format!("{}: {e}", out.display()))?;
    hf.write_tiff(file).map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!("wrote {}: {side}² samples at {} m", out.display(), ranges::RANGE_SPACING_M);
    Ok(())
}

/// `terrain hillshade`: each input area-averaged to `spacing_m`, its centred `side`² square
/// hillshaded, the squares side by side (8 white pixels apart) in one grey PNG.
pub(crate) fn hillshade(inputs: &[PathBuf], spacing_m: f64, side: usize, out: &std::path::Path) -> Result<(), String> {
    use terrain::dem::{Heightfield, PngScale};
    const GAP: usize = 8;
    let mut panels = Vec::new();
    for path in inputs {
        let hf = Heightfield::read_path(path, manifest_spacing(path), PngScale::default()).map_err(|e| format!("{}: {e}", path.display()))?;
        let hf = if hf.spacing_m < spacing_m - 1e-9 { hf.resample_area(spacing_m).map_err(|e| format!("{}: {e}", path.display()))? } else { hf };
        let s = side.min(hf.width).min(hf.height);
        panels.push(hf.window((hf.width - s) / 2, (hf.height - s) / 2, s, s));
    }
    let height = panels.iter().map(|p| p.height).max().unwrap_or(0);
    let width = panels.iter().map(|p| p.width).sum::<usize>() + GAP * panels.len().saturating_sub(1);
    let mut grey = vec![255u8; width * height];
    let mut x0 = 0;
    for p in &panels {
        for (k, v) in p.hillshade().into_iter().enumerate() {
            grey[(k / p.width) * width + x0 + k % p.width] = v;
        }
        x0 += p.width + GAP;
    }
    let file = std::fs::File::create(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    enc.write_header().and_then(|mut w| w.write_image_data(&grey)).map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!("wrote {}: {} panels of {}² samples at {spacing_m} m", out.display(), panels.len(), panels.first().map_or(0, |p| p.width));
    Ok(())
}

/// The spacing (metres) `manifest.json` beside `path` gives its file (`metres_per_pixel` of
/// the entry whose `file` is its name), for DEMs whose TIFF carries no pixel size.
fn manifest_spacing(path: &std::path::Path) -> Option<f64> {
    let text = std::fs::read_to_string(path.parent()?.join("manifest.json")).ok()?;
    let manifest: serde_json::Value = serde_json::from_str(&text).ok()?;
    let name = path.file_name()?.to_str()?;
    let entries = manifest.get("dems").or(Some(&manifest))?.as_array()?;
    entries.iter().find(|d| d["file"].as_str() == Some(name))?["metres_per_pixel"].as_f64()
}
