//! `terrain`: the command-line side of the terrain tool.
//!
//! `terrain world --seed S --tiles X0 Y0 W H --out region.tif [--source procedural]`
//! writes the 32 m heights (metres) of tiles [X0, X0+W) × [Y0, Y0+H) as a float32 TIFF.
//!
//! `terrain enhance --input in.tif --input-res 32 --output-res 1 --out out.tif` refines a DEM
//! with the TEM ladder (the world's patch code path) and writes the same extent at the output
//! spacing. `terrain tem-probe` prints the digest of the fixed probe per level (CPU), which the
//! browser test compares with the page's WebGPU result.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use terrain::world::{NoiseParams, ProceduralSource, TileSource, export};

/// Most tiles `terrain world` writes at once (64 × 64 tiles: 8192² samples, 256 MiB).
const MAX_EXPORT_TILES: u64 = 4096;

/// The terrain tool's command line: export the world, refine DEMs with the learned ladder,
/// train and evaluate the models.
#[derive(Parser, Debug)]
#[command(name = "terrain", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// The networks of sketch-to-terrain.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum SketchModel {
    /// The sketch → terrain generator (pix2pix).
    Generator,
    /// The VAE over sketches (variants, interpolation).
    Vae,
}

/// Where tiles come from.
#[derive(Clone, Copy, Debug, ValueEnum)]
enum Source {
    /// Seeded fBm noise (the page's procedural world).
    Procedural,
    /// The learned world: the TCM at 128 m and its ×4 step to 32 m (weights from --weights).
    Tcm,
}

/// How many views of a sketch the generator averages (`--views`), shared by the sketch commands.
#[derive(clap::Args, Debug)]
struct Views {
    /// Views averaged: the generator runs on this many rotations/flips of the sketch (1–8)
    /// and the outputs, turned back, are averaged (8: the terrain turns exactly with the
    /// sketch; 1: what the page shows while drawing, 8× faster).
    #[arg(long = "views", value_name = "N", default_value_t = terrain::models::sketch::CLI_VIEWS as u32, value_parser = clap::value_parser!(u32).range(1..=8))]
    count: u32,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Write the 32 m heights (metres) of a rectangle of tiles as a float32 GeoTIFF.
    World {
        /// World seed.
        #[arg(long)]
        seed: u64,
        /// Tiles [X0, X0+W) × [Y0, Y0+H): 128 × 128 samples each.
        #[arg(long, num_args = 4, value_names = ["X0", "Y0", "W", "H"], allow_negative_numbers = true, required = true)]
        tiles: Vec<i64>,
        /// Output GeoTIFF.
        #[arg(long)]
        out: PathBuf,
        /// Tile source.
        #[arg(long, value_enum, default_value_t = Source::Procedural)]
        source: Source,
        /// Folder of the learned world's weights (--source tcm; default: ./weights, else the
        /// crate's).
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Refine a DEM (float32 TIFF in metres or 16-bit PNG) with the learned ×2 ladder.
    Enhance {
        /// Input DEM (.tif, .tiff, .png).
        #[arg(long)]
        input: PathBuf,
        /// Input spacing (m per pixel): 32, 16, 8, 4 or 2.
        #[arg(long)]
        input_res: f64,
        /// Output spacing (m per pixel): 16, 8, 4, 2 or 1, finer than the input.
        #[arg(long)]
        output_res: f64,
        /// Output GeoTIFF.
        #[arg(long)]
        out: PathBuf,
        /// Folder of the TEM weights (default: ./weights, else the crate's).
        #[arg(long)]
        weights: Option<PathBuf>,
        /// Patches per model call.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
        batch: u32,
    },
    /// Print the digest of the fixed TEM probe per level (CPU), for the browser test.
    TemProbe {
        /// Folder of the TEM weights.
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Write the TEM weights and the probe (input and our output) of every level as JSON, for
    /// reference runtimes (tools/tem_vs_onnx.py rebuilds the network in ONNX Runtime).
    TemExport {
        /// Folder of the TEM weights.
        #[arg(long)]
        weights: Option<PathBuf>,
        /// Output JSON file.
        #[arg(long)]
        out: PathBuf,
    },
    /// Write the sketch generator's weights and a probe (an example sketch's input and our
    /// output before the band scale) as JSON, for reference runtimes (tools/sketch_vs_onnx.py
    /// rebuilds the network in ONNX Runtime).
    SketchExport {
        /// Folder of the sketch weights.
        #[arg(long)]
        weights: Option<PathBuf>,
        /// Output JSON file.
        #[arg(long)]
        out: PathBuf,
    },
    /// Time the sketch generator on the CPU: prints JSON with the median milliseconds of one
    /// forward pass (one view of a 256² sketch, without the input's baseline).
    SketchBench {
        /// Threads (default: every core).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=256))]
        threads: Option<u32>,
        /// Timed calls (after one warm-up call).
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=10_000))]
        repeats: u32,
        /// Folder of the sketch weights.
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Write a weight file with its float32 tensors stored as float16 (every shipped weight
    /// file: half the download).
    HalfWeights {
        /// Weight file (burnpack) to read.
        #[arg(long)]
        input: PathBuf,
        /// Weight file to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// Average weight files of one network (e.g. a run's last checkpoints) into one float32
    /// file.
    AverageWeights {
        /// Weight files (burnpack) to average (repeat the flag).
        #[arg(long, required = true)]
        input: Vec<PathBuf>,
        /// Weight file to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// Time TEM inference on the CPU: prints JSON with the median milliseconds per quad
    /// (input 100² incl. margin → 200²).
    TemBench {
        /// Threads (default: every core).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=256))]
        threads: Option<u32>,
        /// Level of the ladder (0 = 32 → 16 m).
        #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..5))]
        level: u32,
        /// Quads per model call.
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
        batch: u32,
        /// Timed calls (after one warm-up call).
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=10_000))]
        repeats: u32,
        /// Folder of the TEM weights.
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Train the five TEM models on the CPU (feature `train`).
    #[cfg(feature = "train")]
    TrainTem(TrainArgs),
    /// Train the learned world on the CPU, resumable: the TCM (128 m tiles from their
    /// neighbours) and its ×4 step to 32 m, one step of each in turn (feature `train`).
    #[cfg(feature = "train")]
    TrainTcm {
        /// Folder of DEMs (float32 TIFF) with manifest.json.
        #[arg(long)]
        dem_dir: PathBuf,
        /// Optimiser steps to run now (a resumed run adds them to the steps it had).
        #[arg(long, default_value_t = 2000)]
        steps: usize,
        /// Continue the run saved in the checkpoint folder.
        #[arg(long)]
        resume: bool,
        /// Checkpoint folder (generator, discriminator, optimisers, progress).
        #[arg(long, default_value = "train-runs/tcm")]
        checkpoint: PathBuf,
        /// Save a checkpoint every N steps.
        #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u64).range(1..))]
        checkpoint_every: u64,
        /// Windows per step (a new run only; a resumed one keeps its own).
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=256))]
        batch: u64,
        /// Weight of the adversarial term (0: L1 only; a new run only).
        #[arg(long, default_value_t = 1.0)]
        adversarial: f32,
        /// Start a new run from the weight files in this folder: the TCM from a generator of
        /// today's input layout, or of the first one (7 channels; the ruggedness channel then
        /// starts at zero weight), and the ×4 step from its own file.
        #[arg(long, conflicts_with = "resume")]
        init: Option<PathBuf>,
        /// Weight of the ruggedness term: |ln relief of the made tile − ln relief of the real
        /// one| (a new run only; 0: none).
        #[arg(long, default_value_t = 0.0)]
        ruggedness: f32,
        /// Weight of the drainage term: the mean depth of the made tile's closed depressions
        /// below their fill level (a new run only; 0: none).
        #[arg(long, default_value_t = 0.0)]
        drainage: f32,
        /// Weight of the coarse term: the mean |difference| between the 8×8-sample block means
        /// of the made tile and of the real one (a new run only; 0: none).
        #[arg(long, default_value_t = 0.0)]
        coarse: f32,
        /// Weight of the L1 term far from any given neighbour, and everywhere in phase-0
        /// windows (no neighbour given); a new run only; 1: full L1 everywhere.
        #[arg(long, default_value_t = 1.0)]
        free_l1: f32,
        /// Reach (samples at 128 m) of the full L1 weight from the given neighbours: beyond
        /// it L1 fades to --free-l1 (a new run only; 0: full L1 wherever a neighbour is given).
        #[arg(long, default_value_t = 0.0)]
        l1_reach: f32,
        /// Judge each made tile joined to its given neighbours, as the world shows it (a new
        /// run only).
        #[arg(long)]
        joined: bool,
        /// Weight of the dome term: per phase, |mean dome height of the made tiles − of the
        /// real ones| over the batch (a new run only; 0: none).
        #[arg(long, default_value_t = 0.0)]
        dome: f32,
        /// The discriminator also sees the window's slopes (a new run only).
        #[arg(long)]
        disc_slopes: bool,
        /// Weight of the position term: how much the made tiles' roughness depends on the
        /// position inside the tile (0: none; with --resume it replaces the saved weight).
        #[arg(long)]
        position: Option<f32>,
        /// Train only the TCM; the ×4 step's checkpoint stays as it is.
        #[arg(long, conflicts_with = "grow_only")]
        tcm_only: bool,
        /// Train only the ×4 step; the TCM's checkpoint stays as it is.
        #[arg(long)]
        grow_only: bool,
        /// Weight of the ×4 step's cell-position term: how much its steps depend on the place
        /// inside the 128 m cell (0: none; with --resume it replaces the saved weight).
        #[arg(long)]
        grow_position: Option<f32>,
        #[command(flatten)]
        run: RunArgs,
    },
    /// Compare the learned and the procedural world with the held-out east third of every DEM
    /// at 32 m or finer: geomorphometric statistics over 128 and 256-sample windows, their
    /// distance to the real ones, the seam and crease figures (feature `train`).
    #[cfg(feature = "train")]
    EvalTcm {
        /// Folder of DEMs (float32 TIFF) with manifest.json.
        #[arg(long)]
        dem_dir: PathBuf,
        /// Folder of the learned world's weights.
        #[arg(long, default_value = "weights")]
        weights: PathBuf,
        /// Worlds (seeds 1..=N) of 6×6 tiles each to measure.
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u64).range(1..=64))]
        seeds: u64,
    },
    /// Turn a sketch (256×256 RGB PNG in the format's palette) into terrain: a 256×256 16-bit
    /// grey PNG of relative heights (0 = the lowest point, 65535 the highest).
    Sketch {
        /// Sketch PNG.
        #[arg(long)]
        input: PathBuf,
        /// Output 16-bit PNG.
        #[arg(long)]
        out: PathBuf,
        /// Folder of the sketch generator's weights (default: ./weights, else the crate's).
        #[arg(long)]
        weights: Option<PathBuf>,
        #[command(flatten)]
        views: Views,
    },
    /// Train the sketch generator on the CPU from sketches extracted from real DEMs, resumable
    /// (feature `train`).
    #[cfg(feature = "train")]
    TrainSketch {
        /// Folder of DEMs (float32 TIFF) with manifest.json.
        #[arg(long)]
        dem_dir: PathBuf,
        /// Optimiser steps to run now (a resumed run adds them to the steps it had).
        #[arg(long, default_value_t = 2000)]
        steps: usize,
        /// Continue the run saved in the checkpoint folder.
        #[arg(long)]
        resume: bool,
        /// Checkpoint folder (generator, discriminator, optimisers, progress).
        #[arg(long, default_value = "train-runs/sketch")]
        checkpoint: PathBuf,
        /// Save a checkpoint (and score the validation pairs) every N steps.
        #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(1..))]
        checkpoint_every: u64,
        /// Crops per step (a new run only).
        #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=256))]
        batch: u64,
        /// Side of the training crops: a multiple of 16 (generator) or 64 (VAE) up to 256 (a new
        /// run only).
        #[arg(long, default_value_t = 128)]
        crop: usize,
        /// Pairs kept in memory (a new run only).
        #[arg(long, default_value_t = 384, value_parser = clap::value_parser!(u64).range(1..=100_000))]
        pool: u64,
        /// Weight of the adversarial term against L1 (0: L1 only; a new run only).
        #[arg(long, default_value_t = 0.01)]
        adversarial: f32,
        /// Held-out pairs scored at each checkpoint.
        #[arg(long, default_value_t = 48)]
        validation: usize,
        /// Which network to train.
        #[arg(long, value_enum, default_value_t = SketchModel::Generator)]
        model: SketchModel,
        /// Start the generator from the weights in this folder (e.g. `weights`) instead of
        /// random ones (a new run only).
        #[arg(long)]
        init: Option<PathBuf>,
        /// Train (and validate) only on windows whose ground extent is at most this many metres
        /// (the format's tiles are 512 m; a new run only).
        #[arg(long)]
        max_extent_m: Option<f64>,
        /// Train (and validate) only on windows whose ground extent is at least this many
        /// metres (a new run only).
        #[arg(long)]
        min_extent_m: Option<f64>,
        /// Train (and validate) only on these DEMs of the manifest (ids, comma-separated; a
        /// new run only). Default: every DEM.
        #[arg(long, value_delimiter = ',')]
        dems: Vec<String>,
        /// Also train on the pairs in this folder (the format's 512×256 files, e.g. the sketch
        /// authors' pairs), in their 8 rotations/flips (a new run only).
        #[arg(long)]
        format_pairs: Option<PathBuf>,
        /// Hold out the files of --format-pairs whose name contains this (repeatable, e.g. an
        /// area): they are scored at every checkpoint instead of trained on.
        #[arg(long)]
        format_exclude: Vec<String>,
        /// Share (0–1) of each batch's crops taken from --format-pairs.
        #[arg(long, default_value_t = 0.5)]
        format_share: f32,
        /// The generator's per-pixel loss: l1 (pix2pix), l2 (least expected RMSE) or band-l1
        /// (L1 after the band scale the CLI applies; whole tiles) (a new run only).
        #[arg(long, value_enum, default_value_t = terrain::train::sketch::PixelLoss::L1)]
        loss: terrain::train::sketch::PixelLoss,
        /// Adam learning rate of the generator (the discriminator's is half; a new run only).
        #[arg(long, default_value_t = 2e-4)]
        lr: f64,
        /// Also keep each checkpoint's generator as snapshots/gen_STEP.bpk in the checkpoint
        /// folder (for `terrain average-weights`).
        #[arg(long)]
        snapshots: bool,
        #[command(flatten)]
        run: RunArgs,
    },
    /// Propose variants of a sketch: sketches with codes near its own in the sketch VAE, each
    /// turned into terrain. Writes variant_K_sketch.png and variant_K_dem.png (16-bit) per
    /// variant.
    SketchVariants {
        /// Sketch PNG.
        #[arg(long)]
        input: PathBuf,
        /// Number of variants.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
        n: u32,
        /// Output folder (created if missing).
        #[arg(long)]
        out_dir: PathBuf,
        /// Seed of the variants (the same seed gives the same variants).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Folder of the sketch models' weights (default: ./weights, else the crate's).
        #[arg(long)]
        weights: Option<PathBuf>,
        #[command(flatten)]
        views: Views,
    },
    /// Make a sketch from a window of a DEM with the project's extractor (bands = height
    /// quarters, ridges and valleys from drainage): a 256×256 sketch PNG, and optionally the
    /// window's terrain as the 16-bit PNG the sketch stands for.
    SketchExtract {
        /// Input DEM (.tif, .tiff, .png).
        #[arg(long)]
        dem: PathBuf,
        /// Window: left column, top row and side (samples); it is resampled to 256².
        #[arg(long, num_args = 3, value_names = ["X0", "Y0", "SIDE"], required = true)]
        window: Vec<u32>,
        /// Output sketch PNG.
        #[arg(long)]
        out: PathBuf,
        /// Also write the window's terrain (16-bit PNG, 0 = lowest, 65535 = highest).
        #[arg(long)]
        dem_out: Option<PathBuf>,
    },
    /// Score sketch-to-terrain on the authors' pairs (512×256 PNG: sketch | 8-bit DEM): per pair
    /// and mean RMSE / PSNR on the 0–255 scale of the generator and of the non-learned baseline
    /// (linear interpolation between band borders), and how closely the project's extractor
    /// reproduces each sketch from its DEM half.
    EvalSketch {
        /// Folder of pair PNGs.
        #[arg(long)]
        pairs: PathBuf,
        /// Folder of the sketch generator's weights (default: ./weights, else the crate's).
        #[arg(long)]
        weights: Option<PathBuf>,
        #[command(flatten)]
        views: Views,
    },
    /// Evaluate the TEM on the held-out east third of every DEM (feature `train`).
    #[cfg(feature = "train")]
    EvalTem {
        /// Folder of DEMs (float32 TIFF) with manifest.json.
        #[arg(long)]
        dem_dir: PathBuf,
        /// Folder of the TEM weights.
        #[arg(long, default_value = "weights")]
        weights: PathBuf,
        /// Validation windows per level.
        #[arg(long, default_value_t = 64)]
        windows: usize,
    },
}

/// Where and how long a training runs (`--backend`, `--minutes`, `--checkpoint-minutes`),
/// shared by the training commands.
#[cfg(feature = "train")]
#[derive(clap::Args, Debug)]
struct RunArgs {
    /// cpu: burn's CPU backend; gpu: burn's wgpu backend on the default Vulkan adapter (a
    /// GPU's driver, or Mesa's lavapipe where there is none).
    #[arg(long, value_enum, default_value_t = terrain::train::Backend::Cpu)]
    backend: terrain::train::Backend,
    /// Stop after this many minutes of wall-clock time, with a checkpoint (default: run all
    /// the steps).
    #[arg(long)]
    minutes: Option<f64>,
    /// Also save a checkpoint every this many minutes of wall-clock time.
    #[arg(long)]
    checkpoint_minutes: Option<f64>,
}

#[cfg(feature = "train")]
impl RunArgs {
    /// The autodiff device and the wall-clock budget, with the backend logged.
    fn start(&self) -> Result<(burn::tensor::Device, terrain::train::Budget), String> {
        let budget = terrain::train::Budget::new(self.minutes, self.checkpoint_minutes)?;
        let device = self.backend.device()?;
        eprintln!("backend: {}", self.backend.describe());
        Ok((device, budget))
    }
}

/// Training examples per second over a run's steps after its first (the GPU backend compiles
/// its kernels in the first step): 0 until a second step has run.
#[cfg(feature = "train")]
struct StepRate {
    /// The step count the run started from.
    first: usize,
    /// Step count and seconds (of step time) after the first step.
    from: Option<(usize, f64)>,
}

#[cfg(feature = "train")]
impl StepRate {
    /// A rate for a run starting at step count `first`.
    fn new(first: usize) -> Self {
        Self { first, from: None }
    }

    /// Notes the progress after a step: the step count and the seconds so far.
    fn after_step(&mut self, step: usize, seconds: f64) {
        if step == self.first + 1 {
            self.from = Some((step, seconds));
        }
    }

    /// Examples/s at step count `step` and `seconds`, with `batch` examples a step.
    fn examples_per_s(&self, step: usize, seconds: f64, batch: usize) -> f64 {
        match self.from {
            Some((s0, t0)) if seconds > t0 => ((step - s0) * batch) as f64 / (seconds - t0),
            _ => 0.0,
        }
    }
}

/// Arguments of `terrain train-tem`.
#[cfg(feature = "train")]
#[derive(clap::Args, Debug)]
struct TrainArgs {
    /// Folder of DEMs (float32 TIFF) with manifest.json.
    #[arg(long)]
    dem_dir: PathBuf,
    /// Chained optimiser steps.
    #[arg(long)]
    steps: Option<usize>,
    /// Single-level fine-tuning steps on real data after the chained ones.
    #[arg(long)]
    finetune: Option<usize>,
    /// Save a checkpoint every N steps (0: never).
    #[arg(long, default_value_t = 100)]
    checkpoint_every: usize,
    /// Chains per step.
    #[arg(long)]
    batch: Option<usize>,
    /// Consecutive levels per chain (1..=5).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=5))]
    chain: Option<u32>,
    /// Adam learning rate.
    #[arg(long)]
    lr: Option<f64>,
    /// Seed of the sampler.
    #[arg(long)]
    seed: Option<u64>,
    /// Output folder of the weights.
    #[arg(long, default_value = "weights")]
    out: PathBuf,
    /// Start the five models from the weight files in this folder (e.g. `weights`, or the
    /// `checkpoint` folder of an earlier run) instead of random weights.
    #[arg(long)]
    init: Option<PathBuf>,
    #[command(flatten)]
    run: RunArgs,
}

/// The tile rectangle of `--tiles X0 Y0 W H`, checked without overflow: W, H ≥ 1, W·H ≤
/// [`MAX_EXPORT_TILES`], every coordinate within ±2³⁰.
fn tile_rect(t: &[i64]) -> Result<(i32, i32, u32, u32), String> {
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

fn world(seed: u64, tiles: &[i64], out: &std::path::Path, source: Source, weights: Option<PathBuf>) -> Result<(), String> {
    let (x0, y0, w, h) = tile_rect(tiles)?;
    let src: Box<dyn TileSource> = match source {
        Source::Procedural => Box::new(ProceduralSource::new(NoiseParams::default())),
        Source::Tcm => {
            let models = terrain::world::learned::LearnedModels::load_dir(&weights_dir(weights))?;
            Box::new(terrain::world::learned::LearnedSource::new(std::sync::Arc::new(models), terrain::models::cpu::default_threads()))
        }
    };
    let hf = export::region(seed, src, x0, y0, w, h);
    let file = std::fs::File::create(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    hf.write_tiff(std::io::BufWriter::new(file)).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("wrote {}: {}×{} samples at {} m", out.display(), hf.width, hf.height, hf.spacing_m);
    Ok(())
}

/// The weights folder: `--weights`, else `weights/` here, else the crate's own.
fn weights_dir(given: Option<PathBuf>) -> PathBuf {
    if let Some(w) = given {
        return w;
    }
    let here = PathBuf::from("weights");
    if here.join("manifest.json").exists() { here } else { PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/weights")) }
}

fn enhance(input: &std::path::Path, input_res: f64, output_res: f64, out: &std::path::Path, weights: Option<PathBuf>, batch: usize) -> Result<(), String> {
    use terrain::dem::{Heightfield, PngScale};
    let (first, last) = terrain::enhance::levels_for(input_res, output_res).map_err(|e| e.to_string())?;
    let hf = Heightfield::read_path(input, Some(input_res), PngScale::default()).map_err(|e| format!("{}: {e}", input.display()))?;
    terrain::enhance::output_size(hf.width, hf.height, last - first + 1).map_err(|e| e.to_string())?;
    let tem = terrain::models::tem::TemSet::load_dir(&weights_dir(weights), &terrain::models::tem::Exec::cpu())?;
    let t = std::time::Instant::now();
    let mut last_report = (usize::MAX, 0);
    let (result, stats) = terrain::enhance::enhance(&hf, input_res, output_res, &tem, batch, &mut |level, done, total| {
        if level != last_report.0 || done * 10 / total.max(1) != last_report.1 {
            last_report = (level, done * 10 / total.max(1));
            eprintln!("level {level} ({} m): {done}/{total} patches", terrain::models::tem::LEVEL_SPACING_M[level]);
        }
    }).map_err(|e| e.to_string())?;
    let file = std::fs::File::create(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    result.write_tiff(std::io::BufWriter::new(file)).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!(
        "wrote {}: {}×{} at {} m from {}×{} at {input_res} m; {} patches in {:.1} s ({:.1} ms per patch)",
        out.display(), result.width, result.height, result.spacing_m, hf.width, hf.height, stats.quads_made, t.elapsed().as_secs_f64(), stats.ms_per_quad()
    );
    Ok(())
}

fn tem_probe(weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::models::tem::{Exec, LEVELS, PROBE_SIDE, TemSet, probe_input, probe_json};
    let tem = TemSet::load_dir(&weights_dir(weights), &Exec::cpu())?;
    let levels = (0..LEVELS).map(|k| tem.enhance_blocking(k, probe_input(k), 1, PROBE_SIDE)).collect::<Result<Vec<_>, _>>()?;
    println!("{}", probe_json("cpu", &levels, Default::default()));
    Ok(())
}

fn half_weights(input: &std::path::Path, out: &std::path::Path) -> Result<(), String> {
    let bytes = std::fs::read(input).map_err(|e| format!("cannot read {}: {e}", input.display()))?;
    let half = terrain::models::cpu::to_half_burnpack(&bytes).map_err(|e| format!("{}: {e}", input.display()))?;
    std::fs::write(out, &half).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("{}: {} → {} bytes", out.display(), bytes.len(), half.len());
    Ok(())
}

fn average_weights(inputs: &[PathBuf], out: &std::path::Path) -> Result<(), String> {
    let files = inputs.iter().map(|p| std::fs::read(p).map_err(|e| format!("cannot read {}: {e}", p.display()))).collect::<Result<Vec<_>, _>>()?;
    let avg = terrain::models::cpu::average_burnpacks(&files)?;
    std::fs::write(out, &avg).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("{}: the mean of {} weight files", out.display(), files.len());
    Ok(())
}

fn tem_export(weights: Option<PathBuf>, out: &std::path::Path) -> Result<(), String> {
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

fn tem_bench(level: usize, batch: usize, repeats: usize, threads: Option<u32>, weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::models::tem::{Exec, PROBE_SIDE, TemSet, probe_input};
    let exec = threads.map_or_else(Exec::cpu, |t| Exec::Cpu { threads: t as usize });
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
    println!("{}", serde_json::json!({ "level": level, "batch": batch, "repeats": repeats, "backend": tem.backend(), "ms_per_quad": ms[ms.len() / 2], "min_ms_per_quad": ms[0] }));
    Ok(())
}

#[cfg(feature = "train")]
fn train_tem(a: TrainArgs) -> Result<(), String> {
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
    println!("{}", serde_json::json!({ "steps": done, "batch": cfg.batch, "chain_levels": cfg.chain_levels, "lr": cfg.lr, "seed": cfg.seed, "final_l1_per_level_scale_units": losses, "backend": a.run.backend, "seconds": step_s, "examples_per_s": rate.examples_per_s(done, step_s, cfg.batch) }));
    Ok(())
}

#[cfg(feature = "train")]
#[allow(clippy::too_many_arguments)]
fn train_tcm(dem_dir: &std::path::Path, steps: usize, resume: bool, checkpoint: &std::path::Path, every: usize, batch: usize, [adversarial, ruggedness, drainage, coarse, free_l1, l1_reach, dome]: [f32; 7], [joined, disc_slopes]: [bool; 2], [position, grow_position]: [Option<f32>; 2], init: Option<&std::path::Path>, [tcm_only, grow_only]: [bool; 2], run_args: &RunArgs) -> Result<(), String> {
    use terrain::train::{grow, pairs, tcm};
    for (flag, w) in [("--adversarial", adversarial), ("--ruggedness", ruggedness), ("--drainage", drainage), ("--coarse", coarse), ("--free-l1", free_l1), ("--l1-reach", l1_reach), ("--dome", dome), ("--position", position.unwrap_or(0.0)), ("--grow-position", grow_position.unwrap_or(0.0))] {
        if !w.is_finite() || w < 0.0 {
            return Err(format!("{flag} must be a finite number ≥ 0, not {w}"));
        }
    }
    let dems = pairs::load_dems(dem_dir)?;
    let grids = tcm::grids(&dems);
    let fine = grow::grids(&dems);
    let names = |v: Vec<&str>| v.join(", ");
    if grids.is_empty() || fine.is_empty() {
        return Err(format!("{} needs DEMs with room for a 3×3-tile window at 128 m ({} found) and for a 224² window at 32 m or finer ({} found) in both splits", dem_dir.display(), grids.len(), fine.len()));
    }
    eprintln!("TCM data, {} DEMs at 128 m: {}", grids.len(), names(grids.iter().map(|g| g.id.as_str()).collect()));
    let (level, level_sd, step) = tcm::tile_mean_stats(&grids);
    eprintln!("real 4 km tile means: level {level:.0} ± {level_sd:.0} m, rms step between neighbours {step:.0} m");
    eprintln!("×4 data, {} DEMs at 32 m: {}", fine.len(), names(fine.iter().map(|g| g.id.as_str()).collect()));
    let fine_ids: Vec<&str> = fine.iter().map(|g| g.id.as_str()).collect();
    let all: Vec<&pairs::Grid> = grids.iter().collect();
    let (fine_coarse, rest): (Vec<_>, Vec<_>) = grids.iter().partition(|g| fine_ids.contains(&g.id.as_str()));
    for (what, set) in [("all", &all), ("32 m or finer", &fine_coarse), ("coarser", &rest)] {
        for split in [pairs::Split::Train, pairs::Split::Validation] {
            if let Some((m, sd, p95)) = tcm::ruggedness_stats(set, split) {
                eprintln!("ruggedness of {what} DEMs ({split:?}): {m:.2} ± {sd:.2}, 95th percentile {p95:.2}");
            }
        }
    }
    let (device, mut budget) = run_args.start()?;
    let cfg = tcm::TcmConfig { batch, adversarial, ruggedness, drainage, coarse, free_l1, l1_reach_px: l1_reach, joined, dome, disc_slopes, position: position.unwrap_or(0.0), ..Default::default() };
    let from = resume.then_some(checkpoint);
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
    let mut run = tcm::start_run(cfg, &device, from.filter(|_| !grow_only), start.as_ref())?;
    if let Some(w) = position {
        run.cfg.position = w;
    }
    let mut up = grow::GrowRun::start(batch, adversarial, &device, from.filter(|_| !tcm_only))?;
    if let Some(dir) = init.filter(|_| !tcm_only) {
        // The shipped file holds float16 weights, which burn's loader does not convert.
        let file = dir.join(grow::GROW_FILE);
        let bytes = std::fs::read(&file).map_err(|e| format!("{}: {e}", file.display()))?;
        let g = terrain::models::grow::GrowCpu::from_burnpack(&bytes).map_err(|e| format!("{}: {e}", file.display()))?;
        up.g = g.into_model(up.g);
    }
    if let Some(w) = grow_position {
        up.position = w;
    }
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
            eprintln!("step {:6}  TCM l1 {:.4} adv {:.3} disc {:.3} pits {:.5} {:.2} s/step | ×4 l1 {:.4} adv {:.3} disc {:.3} {:.2} s/step", step, p.l1, p.adv, p.disc, p.depression, p.seconds / p.step.max(1) as f64, q.l1, q.adv, q.disc, q.seconds / q.step.max(1) as f64);
        }
        if step % every == 0 || step == end || budget.checkpoint_due() {
            if !grow_only {
                run.save(checkpoint)?;
            }
            if !tcm_only {
                up.save(checkpoint)?;
            }
        }
    }
    let summary = |p: &tcm::TcmProgress, rate: &StepRate, batch: usize| serde_json::json!({ "steps": p.step, "seconds": p.seconds, "l1": p.l1, "adv": p.adv, "disc": p.disc, "examples_per_s": rate.examples_per_s(p.step, p.seconds, batch) });
    println!("{}", serde_json::json!({ "tcm": summary(&run.progress, &tcm_rate, run.cfg.batch), "grow": summary(&up.progress, &grow_rate, up.batch), "checkpoint": checkpoint, "backend": run_args.backend }));
    Ok(())
}

#[cfg(feature = "train")]
fn eval_tcm(dem_dir: &std::path::Path, weights: &std::path::Path, seeds: u64) -> Result<(), String> {
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
    let mut sides = Vec::new();
    for side in world_eval::WINDOW_SIDES {
        let real = world_eval::stats_of(&world_eval::real_windows(&dems, side), side);
        if real.is_empty() {
            return Err(format!("no NaN-free {side}² validation window at 32 m or finer in {}", dem_dir.display()));
        }
        let mut worlds = serde_json::Map::new();
        let mut means = Vec::new();
        for (name, rs, _) in &regions {
            let wins: Vec<Vec<f32>> = rs.iter().flat_map(|r| world_eval::windows_of(r, side)).collect();
            let st = world_eval::stats_of(&wins, side);
            let d = geomorph::distance(&st, &real);
            means.push(d[STAT_NAMES.len()]);
            let per: serde_json::Map<String, serde_json::Value> = STAT_NAMES.iter().zip(&d).map(|(n, v)| (n.to_string(), serde_json::json!(v))).collect();
            worlds.insert(name.to_string(), serde_json::json!({ "windows": st.len(), "distance": d[STAT_NAMES.len()], "per_statistic": per, "medians": medians(&st) }));
        }
        sides.push(serde_json::json!({ "window": side, "real_windows": real.len(), "real_medians": medians(&real), "worlds": worlds, "ratio_tcm_over_procedural": means[0] / means[1] }));
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
            f["ms_per_tile"] = serde_json::json!(ms);
            (name.to_string(), f)
        })
        .collect();
    let side = world_eval::WINDOW_SIDES[1];
    let real: Vec<terrain::dem::Heightfield> = world_eval::real_windows(&dems, side).into_iter().map(|w| terrain::dem::Heightfield::new(side, side, terrain::grid::BASE_SPACING_M, w)).collect();
    seams.insert("real_validation_cut_into_tiles".into(), seam_figures(&real));
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
    println!("{}", serde_json::to_string_pretty(&serde_json::json!({ "weights": models.hash, "seeds": seeds, "region_tiles": [SIDE_TILES, SIDE_TILES], "realism": sides, "seams_and_speed": seams, "ruggedness_128m_tiles": ruggedness, "tile_dome_bias_by_phase_128m_validation": domes })).expect("json"));
    Ok(())
}

#[cfg(feature = "train")]
fn eval_tem(dir: PathBuf, weights: PathBuf, windows: usize) -> Result<(), String> {
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
            e.level, e.spacing_m, if e.real { "real" } else { "self-similar" }, e.windows, e.rmse_bicubic, e.rmse_tem, gain, e.psnr_bicubic, e.psnr_tem, edge.join(" ")
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
    println!("chained (terrain enhance path)     in→out     windows  RMSE bicubic  RMSE TEM   gain   PSNR bic  PSNR TEM  seam ratio TEM/bicubic/truth  TEM RMSE by distance to quad edge (px: 0,1,2-3,4-7,8-15,16+)");
    for e in &chained {
        let gain = 100.0 * (1.0 - e.rmse_tem / e.rmse_bicubic.max(1e-12));
        let edge: Vec<String> = e.rmse_by_quad_edge_distance.iter().map(|v| format!("{v:.3}")).collect();
        println!(
            "{:34} {:>3}→{:<3} m ×{:<3} {:5}  {:10.4} m  {:8.4} m  {:5.1}%  {:7.2}  {:8.2}  {:5.3}/{:5.3}/{:5.3}  {}",
            e.data, e.input_m, e.output_m, (e.input_m / e.output_m) as u32, e.windows, e.rmse_bicubic, e.rmse_tem, gain, e.psnr_bicubic, e.psnr_tem, e.seam_ratio, e.seam_ratio_bicubic, e.seam_ratio_truth, edge.join(" ")
        );
    }
    println!("{}", serde_json::json!({ "one_level": evals, "chained": chained }));
    Ok(())
}

/// The sketch generator from a weights folder.
fn sketch_generator(weights: Option<PathBuf>) -> Result<terrain::models::sketch::SketchGenCpu, String> {
    use terrain::models::sketch::{SketchGenCpu, WEIGHT_FILE};
    let path = weights_dir(weights).join(WEIGHT_FILE);
    let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    SketchGenCpu::from_burnpack(&bytes).map_err(|e| format!("{}: {e}", path.display()))
}

/// The probe of `sketch-export` and `sketch-bench`: the first example sketch's network input.
fn sketch_probe() -> Vec<f32> {
    terrain::models::sketch::assemble_input(&terrain::sketch::examples::first().1).0
}

fn sketch_export(weights: Option<PathBuf>, out: &std::path::Path) -> Result<(), String> {
    use terrain::models::sketch::{IN_CHANNELS, SketchScratch, WIDTHS, conv_layers};
    use terrain::sketch::SKETCH_PX;
    let generator = sketch_generator(weights)?;
    let input = sketch_probe();
    let output = generator.forward(&input, SKETCH_PX, &mut SketchScratch::default(), 1);
    let layers: Vec<String> = conv_layers().into_iter().map(|(name, _, _)| name).collect();
    let json = serde_json::json!({
        "side": SKETCH_PX, "in_channels": IN_CHANNELS, "widths": WIDTHS, "layers": layers,
        "convs": generator.convs_json(), "probe_input": input, "probe_output": output,
    });
    std::fs::write(out, json.to_string()).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("wrote {}", out.display());
    Ok(())
}

fn sketch_bench(repeats: usize, threads: Option<u32>, weights: Option<PathBuf>) -> Result<(), String> {
    use terrain::models::sketch::SketchScratch;
    use terrain::sketch::SKETCH_PX;
    let generator = sketch_generator(weights)?;
    let threads = threads.map_or_else(terrain::models::cpu::default_threads, |t| t as usize);
    let input = sketch_probe();
    let mut scratch = SketchScratch::default();
    generator.forward(&input, SKETCH_PX, &mut scratch, threads);
    let mut ms: Vec<f64> = (0..repeats)
        .map(|_| {
            let t = std::time::Instant::now();
            std::hint::black_box(generator.forward(&input, SKETCH_PX, &mut scratch, threads));
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    ms.sort_by(f64::total_cmp);
    println!("{}", serde_json::json!({ "threads": threads, "repeats": repeats, "ms_per_sketch": ms[ms.len() / 2], "min_ms_per_sketch": ms[0] }));
    Ok(())
}

fn sketch(input: &std::path::Path, out: &std::path::Path, weights: Option<PathBuf>, views: usize) -> Result<(), String> {
    use terrain::sketch::{SKETCH_PX, Sketch, write_dem_png16};
    let sk = Sketch::read_path(input).map_err(|e| format!("{}: {e}", input.display()))?;
    let generator = sketch_generator(weights)?;
    let t = std::time::Instant::now();
    let h = generator.generate_views(&sk, views, &mut Default::default(), terrain::models::cpu::default_threads());
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let file = std::fs::File::create(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    write_dem_png16(std::io::BufWriter::new(file), SKETCH_PX, &h).map_err(|e| format!("cannot write {}: {e}", out.display()))?;
    eprintln!("wrote {}: {SKETCH_PX}×{SKETCH_PX} 16-bit relative heights ({views} views, {ms:.0} ms)", out.display());
    Ok(())
}

#[cfg(feature = "train")]
#[allow(clippy::too_many_arguments)]
fn train_sketch(dem_dir: &std::path::Path, steps: usize, resume: bool, checkpoint: &std::path::Path, every: usize, cfg: terrain::train::sketch::SketchConfig, validation: usize, model: SketchModel, init: Option<&std::path::Path>, run_args: &RunArgs, snapshots: bool) -> Result<(), String> {
    use terrain::train::{pairs, sketch};
    if !cfg.adversarial.is_finite() || cfg.adversarial < 0.0 {
        return Err(format!("--adversarial must be a finite number ≥ 0, not {}", cfg.adversarial));
    }
    if !(0.0..=1.0).contains(&cfg.format_share) {
        return Err(format!("--format-share must be between 0 and 1, not {}", cfg.format_share));
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
        return train_sketch_vae(&dems, steps, resume, checkpoint, every, terrain::train::sketch_vae::VaeConfig { batch: cfg.batch, pool: cfg.pool, crop: cfg.crop, ..Default::default() }, validation, &device, &mut budget, run_args.backend);
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
    eprintln!("sketch generator: {} parameters; {:?}; from step {}; pool and {} validation pairs made in {:.1} s", run.g.parameters(), run.cfg, run.progress.step, val.len(), t.elapsed().as_secs_f64());
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
                let dir = checkpoint.join("snapshots");
                std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
                let to = dir.join(format!("gen_{:06}.bpk", p.step));
                std::fs::copy(checkpoint.join(terrain::models::sketch::WEIGHT_FILE), &to).map_err(|e| format!("{}: {e}", to.display()))?;
            }
            last = Some(v);
        }
    }
    let p = &run.progress;
    println!("{}", serde_json::json!({ "steps": p.step, "seconds": p.seconds, "l1": p.l1, "adv": p.adv, "disc": p.disc, "validation": last, "checkpoint": checkpoint, "backend": run_args.backend, "examples_per_s": rate.examples_per_s(p.step, p.seconds, run.cfg.batch) }));
    Ok(())
}

fn sketch_variants(input: &std::path::Path, n: usize, out_dir: &std::path::Path, seed: u64, weights: Option<PathBuf>, views: usize) -> Result<(), String> {
    use terrain::models::sketch_vae::SketchModels;
    use terrain::sketch::{SKETCH_PX, Sketch, write_dem_png16};
    let sk = Sketch::read_path(input).map_err(|e| format!("{}: {e}", input.display()))?;
    let dir = weights_dir(weights);
    let read = |file: &str| std::fs::read(dir.join(file)).map_err(|e| format!("{}: {e}", dir.join(file).display()));
    let SketchModels { generator, vae, .. } = SketchModels::from_bytes(&read(terrain::models::sketch::WEIGHT_FILE)?, &read(terrain::models::sketch_vae::WEIGHT_FILE)?).map_err(|e| format!("{}: {e}", dir.display()))?;
    std::fs::create_dir_all(out_dir).map_err(|e| format!("cannot create {}: {e}", out_dir.display()))?;
    let threads = terrain::models::cpu::default_threads();
    let t = std::time::Instant::now();
    let variants = vae.variants(&sk, n, seed, &mut Default::default(), threads);
    let mut scratch = Default::default();
    let dems: Vec<Vec<f32>> = variants.iter().map(|v| generator.generate_views(v, views, &mut scratch, threads)).collect();
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
fn train_sketch_vae(dems: &[terrain::train::pairs::Dem], steps: usize, resume: bool, checkpoint: &std::path::Path, every: usize, cfg: terrain::train::sketch_vae::VaeConfig, validation: usize, device: &burn::tensor::Device, budget: &mut terrain::train::Budget, backend: terrain::train::Backend) -> Result<(), String> {
    use terrain::train::{pairs, sketch, sketch_vae};
    let t = std::time::Instant::now();
    let mut run = sketch_vae::VaeRun::start(cfg, dems, device, resume.then_some(checkpoint))?;
    let val = sketch::pairs(dems, pairs::Split::Validation, validation, &sketch::WindowChoice::ALL, 0x5EED);
    eprintln!("sketch VAE: {} parameters; {:?}; from step {}; pool and {} validation sketches made in {:.1} s", run.m.parameters(), run.cfg, run.progress.step, val.len(), t.elapsed().as_secs_f64());
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
            eprintln!("validation ({} held-out sketches): bands kept {:.3}, ridge F1 {:.3}, valley F1 {:.3}; variants change {:.3} of the bands", v.sketches, v.band_agreement, v.ridge_f1, v.valley_f1, v.variant_band_change);
            run.save(checkpoint, Some(&v))?;
            last = Some(v);
        }
    }
    let p = &run.progress;
    println!("{}", serde_json::json!({ "steps": p.step, "seconds": p.seconds, "reconstruction": p.l1, "kl": p.adv, "validation": last, "checkpoint": checkpoint, "backend": backend, "examples_per_s": rate.examples_per_s(p.step, p.seconds, run.cfg.batch) }));
    Ok(())
}

fn sketch_extract(dem: &std::path::Path, window: &[u32], out: &std::path::Path, dem_out: Option<PathBuf>) -> Result<(), String> {
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

fn eval_sketch(dir: &std::path::Path, weights: Option<PathBuf>, views: usize) -> Result<(), String> {
    use terrain::sketch::{self, baseline, extract, score};
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png"))).collect();
    files.sort();
    if files.is_empty() {
        return Err(format!("no .png pairs in {}", dir.display()));
    }
    let generator = sketch_generator(weights)?;
    let mut scratch = Default::default();
    let threads = terrain::models::cpu::default_threads();
    let mut rows = Vec::new();
    let mut ms = Vec::new();
    println!("{:36} {:>8} {:>8} {:>9} {:>9} {:>6} {:>8} {:>9}", "pair", "RMSE", "PSNR", "base RMSE", "base PSNR", "bands", "ridge F1", "valley F1");
    for f in &files {
        let file = std::fs::File::open(f).map_err(|e| format!("{}: {e}", f.display()))?;
        let (sk, target) = sketch::read_pair(std::io::BufReader::new(file)).map_err(|e| format!("{}: {e}", f.display()))?;
        let base = baseline::interpolate(&sk);
        let rmse = score::rmse(&base, &target);
        let t = std::time::Instant::now();
        let ours = generator.generate_views(&sk, views, &mut scratch, threads);
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        let e = score::rmse(&ours, &target);
        let ex = extract::extract(&target).ok_or_else(|| format!("{}: flat DEM half", f.display()))?;
        let ag = score::Agreement::between(&ex.sketch, &sk);
        let name = f.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
        println!("{name:36} {e:8.3} {:8.2} {rmse:9.3} {:9.2} {:6.3} {:8.3} {:9.3}", score::psnr(e), score::psnr(rmse), ag.band, ag.ridge_f1(), ag.valley_f1());
        rows.push(serde_json::json!({ "pair": name, "rmse": e, "psnr": score::psnr(e), "rmse_baseline": rmse, "psnr_baseline": score::psnr(rmse), "extractor": {
            "band_agreement": ag.band, "ridge_precision": ag.ridge_precision, "ridge_recall": ag.ridge_recall, "valley_precision": ag.valley_precision, "valley_recall": ag.valley_recall } }));
    }
    let mean = |k: &str| rows.iter().map(|r| r[k].as_f64().unwrap_or(f64::NAN)).sum::<f64>() / rows.len() as f64;
    let mean_ex = |k: &str| rows.iter().map(|r| r["extractor"][k].as_f64().unwrap_or(f64::NAN)).sum::<f64>() / rows.len() as f64;
    let f1 = |p: f64, r: f64| 2.0 * p * r / (p + r).max(1e-12);
    println!("{:36} {:8.3} {:8.2} {:9.3} {:9.2} {:6.3} {:8.3} {:9.3}", "mean", mean("rmse"), mean("psnr"), mean("rmse_baseline"), mean("psnr_baseline"), mean_ex("band_agreement"), f1(mean_ex("ridge_precision"), mean_ex("ridge_recall")), f1(mean_ex("valley_precision"), mean_ex("valley_recall")));
    ms.sort_by(f64::total_cmp);
    println!("{}", serde_json::json!({ "pairs": rows.len(), "mean": { "rmse": mean("rmse"), "psnr": mean("psnr"), "rmse_baseline": mean("rmse_baseline"), "psnr_baseline": mean("psnr_baseline"),
        "extractor_band_agreement": mean_ex("band_agreement"), "extractor_ridge_precision": mean_ex("ridge_precision"), "extractor_ridge_recall": mean_ex("ridge_recall"),
        "extractor_valley_precision": mean_ex("valley_precision"), "extractor_valley_recall": mean_ex("valley_recall") }, "views": views, "generator_ms_median": ms[ms.len() / 2], "per_pair": rows }));
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::World { seed, tiles, out, source, weights } => world(seed, &tiles, &out, source, weights),
        Command::Enhance { input, input_res, output_res, out, weights, batch } => enhance(&input, input_res, output_res, &out, weights, batch as usize),
        Command::TemProbe { weights } => tem_probe(weights),
        Command::TemExport { weights, out } => tem_export(weights, &out),
        Command::SketchExport { weights, out } => sketch_export(weights, &out),
        Command::SketchBench { repeats, threads, weights } => sketch_bench(repeats as usize, threads, weights),
        Command::HalfWeights { input, out } => half_weights(&input, &out),
        Command::AverageWeights { input, out } => average_weights(&input, &out),
        Command::TemBench { level, batch, repeats, threads, weights } => tem_bench(level as usize, batch as usize, repeats as usize, threads, weights),
        #[cfg(feature = "train")]
        Command::TrainTem(a) => train_tem(a),
        Command::EvalSketch { pairs, weights, views } => eval_sketch(&pairs, weights, views.count as usize),
        Command::Sketch { input, out, weights, views } => sketch(&input, &out, weights, views.count as usize),
        Command::SketchExtract { dem, window, out, dem_out } => sketch_extract(&dem, &window, &out, dem_out),
        #[cfg(feature = "train")]
        Command::TrainSketch { dem_dir, steps, resume, checkpoint, checkpoint_every, batch, crop, pool, adversarial, validation, model, init, max_extent_m, min_extent_m, dems, format_pairs, format_exclude, format_share, loss, lr, run, snapshots } => {
            let format_share = if format_pairs.is_some() { format_share } else { 0.0 };
            let cfg = terrain::train::sketch::SketchConfig { batch: batch as usize, crop, pool: pool as usize, adversarial, windows: terrain::train::sketch::WindowChoice { dems, min_extent_m, max_extent_m }, format_pairs, format_exclude, format_share, lr, loss, ..Default::default() };
            train_sketch(&dem_dir, steps, resume, &checkpoint, checkpoint_every as usize, cfg, validation, model, init.as_deref(), &run, snapshots)
        }
        Command::SketchVariants { input, n, out_dir, seed, weights, views } => sketch_variants(&input, n as usize, &out_dir, seed, weights, views.count as usize),
        #[cfg(feature = "train")]
        Command::EvalTem { dem_dir, weights, windows } => eval_tem(dem_dir, weights, windows),
        #[cfg(feature = "train")]
        Command::EvalTcm { dem_dir, weights, seeds } => eval_tcm(&dem_dir, &weights, seeds),
        #[cfg(feature = "train")]
        Command::TrainTcm { dem_dir, steps, resume, checkpoint, checkpoint_every, batch, adversarial, init, ruggedness, drainage, coarse, free_l1, l1_reach, joined, dome, disc_slopes, position, tcm_only, grow_only, grow_position, run } => {
            train_tcm(&dem_dir, steps, resume, &checkpoint, checkpoint_every as usize, batch as usize, [adversarial, ruggedness, drainage, coarse, free_l1, l1_reach, dome], [joined, disc_slopes], [position, grow_position], init.as_deref(), [tcm_only, grow_only], &run)
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // Usage errors exit 2 (clap); a command that could not do its work exits 1.
            eprintln!("terrain: {e}");
            ExitCode::from(1)
        }
    }
}
