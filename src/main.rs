//! `terrain`: the command-line side of the terrain tool.
//!
//! `terrain world --seed S --tiles X0 Y0 W H --out region.tif [--source procedural]`
//! writes the 32 m heights (metres) of tiles [X0, X0+W) × [Y0, Y0+H) as a float32 TIFF.
//!
//! `terrain enhance --input in.tif --output-res 1 --out out.tif` refines a DEM
//! with the TEM ladder (the world's patch code path) and writes the same extent at the output
//! spacing. `terrain tem-probe` prints the digest of the fixed probe per level (CPU), which the
//! browser test compares with the page's WebGPU result.

mod cli;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use cli::{bench::*, render::*, sketch::*, tem::*, world::*};
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
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
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

/// The region of the world a command writes, and the world it comes from.
#[derive(clap::Args, Debug)]
struct RegionArgs {
    /// World seed.
    #[arg(long)]
    seed: u64,
    /// Tiles [X0, X0+W) × [Y0, Y0+H): 128 × 128 samples each.
    #[arg(long, num_args = 4, value_names = ["X0", "Y0", "W", "H"], allow_negative_numbers = true, required = true)]
    tiles: Vec<i64>,
    /// Output file, in the format of its extension: .tif (float32 GeoTIFF), .png (16-bit
    /// grey) or .raw (16-bit little-endian), each of those two with a JSON sidecar stating
    /// the metres of 0 and 65535 and the spacing, or .glb (binary glTF mesh with normals).
    #[arg(long)]
    out: PathBuf,
    /// Resample to a square of 2ⁿ+1 samples per side (for Unity and Unreal terrains).
    #[arg(long)]
    pow2_plus_1: bool,
    /// Tile source.
    #[arg(long, value_enum, default_value_t = Source::Procedural)]
    source: Source,
    /// Folder of the learned world's weights (--source tcm; default: ./weights, else the
    /// crate's).
    #[arg(long)]
    weights: Option<PathBuf>,
    /// Pin a DEM (32 m or finer) into the learned world (--source tcm): FILE@I,J puts its
    /// north-west corner on tile (I, J), FILE@I,J,M also gives its spacing M in metres (for
    /// a file without its own); it is area-averaged to 32 m, and its whole tiles are kept
    /// exactly while the world grows around them. Repeatable.
    #[arg(long, value_name = "FILE@I,J[,M]")]
    pin: Vec<String>,
    /// The page's sketch world (--source tcm): a sketch PNG (the format's palette) made
    /// into terrain as the page draws it (one view of the generator, weights from
    /// --weights), --relief metres from its lowest to its highest point, --extent-m across,
    /// pinned on the tiles it lies on (8 km: tiles (−1, −1)–(0, 0); 4 km or less: tile (0, 0))
    /// with the learned world grown around it.
    #[arg(long, value_name = "SKETCH.png")]
    sketch: Option<PathBuf>,
    /// Relief of --sketch: metres from its lowest to its highest point (10–8000).
    #[arg(long, default_value_t = terrain::world::sketched::DEFAULT_RELIEF_M)]
    relief: f64,
    /// Extent of --sketch: metres across on the ground (512–8192), which the generator is
    /// told, as the page's extent slider.
    #[arg(long, value_parser = sketch_world_extent, default_value_t = terrain::world::sketched::SKETCH_EXTENT_M)]
    extent_m: f64,
}

/// `terrain export --format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum ExportFormat {
    /// 16-bit grey PNG + JSON sidecar.
    Png16,
    /// 16-bit little-endian RAW + JSON sidecar.
    Raw,
    /// float32 GeoTIFF.
    Tif,
    /// Binary glTF mesh with normals.
    Glb,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Write the 32 m heights (metres) of a rectangle of tiles as a float32 GeoTIFF.
    World {
        #[command(flatten)]
        region: RegionArgs,
    },
    /// Export a rectangle of tiles at a spacing: the 32 m tiles (as `world`), or refined by the
    /// learned detail (TEM) to 16, 8, 4, 2 or 1 m (as `enhance`), written as --format says.
    Export {
        #[command(flatten)]
        region: RegionArgs,
        /// Metres between samples: 32 (the tiles), 16, 8, 4, 2 or 1 (refined by the TEM, weights
        /// from --weights).
        #[arg(long, default_value_t = 32.0)]
        spacing: f64,
        /// File format; the --out file's extension must agree (.png, .raw, .tif, .glb).
        #[arg(long, value_enum)]
        format: Option<ExportFormat>,
    },
    /// Write the learned world's range field (its macro field: ranges and main valleys eroded
    /// at 1,024 m, `world::ranges`) over a square around the origin as a float32 GeoTIFF.
    RangeField {
        /// World seed.
        #[arg(long)]
        seed: u64,
        /// Side of the square (samples of 1,024 m), centred on the origin.
        #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u32).range(16..=2048))]
        side: u32,
        /// Output file (.tif).
        #[arg(long)]
        out: PathBuf,
    },
    /// Draw what a share link shows, as the page draws it once its view is whole, into a PNG:
    /// the page's core driven natively (learned tiles and detail on the CPU) and its renderer
    /// on a native Vulkan adapter. Prints the frames it took and each draw's milliseconds.
    Render {
        /// The link: a whole address (`…?tem=off#v=2&seed=…`) or only its fragment.
        #[arg(long)]
        link: String,
        /// Picture size in pixels, WIDTHxHEIGHT.
        #[arg(long, default_value = "1280x900", value_parser = picture_size)]
        size: [u32; 2],
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Folder of the weights (default: ./weights, else the crate's).
        #[arg(long)]
        weights: Option<PathBuf>,
        /// Threads of the CPU kernels.
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// Draws of the finished view, each timed (the first includes uploading its meshes).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=100))]
        repeats: u32,
    },
    /// Hillshade DEMs side by side into one grey PNG, each area-averaged to one spacing and
    /// cut to the same square around its centre (e.g. a region of the world beside real ranges).
    Hillshade {
        /// Input DEMs (.tif, .tiff, .png), left to right.
        #[arg(long, num_args = 1.., required = true)]
        input: Vec<PathBuf>,
        /// Spacing (metres) every input is area-averaged to.
        #[arg(long, default_value_t = 32.0)]
        spacing_m: f64,
        /// Side (samples) of each input's square, cut around its centre (at most its size).
        #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u32).range(16..=8192))]
        side: u32,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
    },
    /// Refine a DEM (float32 TIFF in metres or 16-bit PNG) with the learned ×2 ladder.
    Enhance {
        /// Input DEM (.tif, .tiff, .png).
        #[arg(long)]
        input: PathBuf,
        /// Input spacing (m per pixel): 32, 16, 8, 4 or 2. Default: the file's own pixel size
        /// (GeoTIFF); needed for a PNG. A value that conflicts with the file's own is refused.
        #[arg(long)]
        input_res: Option<f64>,
        /// Output spacing (m per pixel): 16, 8, 4, 2 or 1, finer than the input.
        #[arg(long)]
        output_res: f64,
        /// Output file, in the format of its extension (as `terrain world --out`).
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
    /// forward pass (one view: a 256² sketch with its 8 px mirrored margin, 272², without the
    /// input's baseline).
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
    /// Time the learned world's networks per phase batch (the TCM's 128 m tiles and the ×4
    /// step to 32 m): one JSON line per model and batch size with milliseconds per batch call
    /// and per tile, on the CPU kernels or (`--gpu`) burn's wgpu backend.
    TileBench {
        /// Tiles per call (repeat the flag; default 1, 4 and 16).
        #[arg(long = "batch", value_parser = clap::value_parser!(u32).range(1..=256))]
        batches: Vec<u32>,
        /// Timed calls per batch size (after one warm-up call).
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=10_000))]
        repeats: u32,
        /// CPU threads (default: every core; ignored with --gpu).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=256))]
        threads: Option<u32>,
        /// Run on burn's wgpu backend (the default Vulkan adapter) instead of the CPU kernels.
        #[arg(long)]
        gpu: bool,
        /// Folder of the world's weights (tcm_128m.bpk, grow_32m.bpk).
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Time the learned world's tiles with the networks run one batch at a time (each phase's
    /// 128 m tiles together, then the ×4 windows) on the CPU kernels or (`--gpu`) burn's wgpu
    /// backend: tiles (0, 0), (1, 0), … of seed 1, from empty caches; prints JSON with the
    /// milliseconds per world tile in all and by part, and the batches' sizes.
    WorldBench {
        /// World tiles to make (a row from (0, 0)).
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
        tiles: u32,
        /// CPU threads (default: every core).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=256))]
        threads: Option<u32>,
        /// Run the networks on burn's wgpu backend (the default Vulkan adapter).
        #[arg(long)]
        gpu: bool,
        /// Folder of the world's weights (tcm_128m.bpk, grow_32m.bpk).
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Calibrate the integer-exact TCM for a weight file: its activation grids from the
    /// float world's network inputs (tiles −3…2 of seeds 1…`seeds`); prints the weight file's
    /// hash and the grids as one JSON line, for `models::tcm::EXACT_CALIBRATIONS`.
    TcmCalibrate {
        /// Worlds (seeds 1 and up) whose tiles the network inputs come from.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
        seeds: u32,
        /// Folder of the world's weights (tcm_128m.bpk, grow_32m.bpk).
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Calibrate the integer-exact ×4 step for a weight file: its grids from the world's ×4
    /// windows (tiles −3…2 of seeds 1…`seeds`); prints the weight file's hash and the grids as
    /// one JSON line, for `models::grow::EXACT_CALIBRATIONS`.
    GrowCalibrate {
        /// Worlds (seeds 1 and up) whose tiles the windows come from.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=64))]
        seeds: u32,
        /// Folder of the world's weights (tcm_128m.bpk, grow_32m.bpk).
        #[arg(long)]
        weights: Option<PathBuf>,
    },
    /// Time TEM inference: prints JSON with the median milliseconds per quad (input 100² incl.
    /// margin → 200²), on the CPU kernels or (`--gpu`) burn's wgpu backend.
    TemBench {
        /// Threads (default: every core).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=256))]
        threads: Option<u32>,
        /// Run on burn's wgpu backend (the default Vulkan adapter) instead of the CPU kernels.
        #[arg(long)]
        gpu: bool,
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
        /// Folder of DEMs (float32 TIFF) with manifest.json (not needed with --mercator-dir).
        #[arg(long, required_unless_present = "mercator_dir")]
        dem_dir: Option<PathBuf>,
        /// Optimiser steps to run now (a resumed run adds them to the steps it had; at most
        /// 10⁹).
        #[arg(long, default_value_t = 2000, value_parser = step_count)]
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
        /// Weight of the coherence term: |orientation coherence around the made tile − around
        /// the real one|, ridges and valleys against round bumps (a new run only; 0: none).
        #[arg(long, default_value_t = 0.0)]
        coherence: f32,
        /// Weight of the position term: how much the made tiles' roughness depends on the
        /// position inside the tile (0: none; with --resume it replaces the saved weight).
        #[arg(long)]
        position: Option<f32>,
        /// Cells a side of the 3×3-tile window's macro field the TCM is given in training,
        /// each the jittered mean of its cell (a new run only): 3, one per 4096 m tile as the
        /// world's field; 6, cells of 2048 m (for a finer coarse level).
        #[arg(long, default_value_t = 3)]
        macro_cells: usize,
        /// Train the TCM on the Web Mercator grids of this folder instead (the layout of
        /// ../shared/dem_coarse: land only, 3×3 median-filtered, in latitude bands), area-averaged
        /// to --spacing-m: a coarse level's generator (needs --tcm-only).
        #[arg(long, requires = "tcm_only")]
        mercator_dir: Option<PathBuf>,
        /// Spacing (metres) the --mercator-dir grids are area-averaged to (grids coarser than it
        /// are left out).
        #[arg(long, default_value_t = 2048.0, requires = "mercator_dir")]
        spacing_m: f64,
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
        /// Also keep each checkpoint's TCM generator as snapshots/tcm_STEP.bpk in the
        /// checkpoint folder (to pick a checkpoint by `terrain eval-tcm` afterwards).
        #[arg(long)]
        snapshots: bool,
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
        /// Output: without --format a 16-bit PNG of relative heights; with it, the file --format
        /// names.
        #[arg(long)]
        out: PathBuf,
        /// Write the sketch's terrain in metres as the page's sketch world has it (256² samples
        /// at 32 m, 8.2 km square, the relief of --relief; with --extent-m, 256² samples at its
        /// own spacing, extent / 256) in this format, with the same options as `export` (.png
        /// and .raw with a JSON sidecar); the --out file's extension must agree.
        #[arg(long, value_enum)]
        format: Option<ExportFormat>,
        /// Relief (metres) from the sketch's lowest to its highest point, with --format.
        #[arg(long, default_value_t = terrain::world::sketched::DEFAULT_RELIEF_M)]
        relief: f64,
        /// With --format: resample to a 2ⁿ+1 square (257²; Unity, Unreal).
        #[arg(long)]
        pow2_plus_1: bool,
        /// Ground extent of the sketch's tile (metres), which the generator is told: by default
        /// the sketch format's tiles (512 m), or with --format the page's sketch world (8,192 m);
        /// 256 to 16,384.
        #[arg(long, value_parser = extent_metres)]
        extent_m: Option<f64>,
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
        /// Optimiser steps to run now (a resumed run adds them to the steps it had; at most
        /// 10⁹).
        #[arg(long, default_value_t = 2000, value_parser = step_count)]
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
        /// Share (0–1) of the training pairs whose sketch is redrawn as a person would draw it:
        /// band borders smoothed into blobs, fewer and smoother strokes (a new run only).
        #[arg(long, default_value_t = 0.0)]
        hand_drawn: f32,
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
        /// Adam learning rate of the generator, in (0, 1] (the discriminator's is half; a new
        /// run only).
        #[arg(long, default_value_t = 2e-4, value_parser = learning_rate)]
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
        /// Also make N variants of each pair's sketch (seed 1) and measure their terrain's
        /// largest and 99th-percentile neighbour step (0–255 scale) against the sketch's own,
        /// and their band islands under 20 px, as the VAE's edit makes them and tidied.
        #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=16))]
        variants: u32,
        /// Ground extent of the pairs' tiles (metres) the generator is told: the format's 512 m
        /// unless said (256 to 16,384).
        #[arg(long, value_parser = extent_metres, default_value_t = terrain::models::sketch::FORMAT_EXTENT_M)]
        extent_m: f64,
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
    #[arg(long, value_parser = step_count)]
    steps: Option<usize>,
    /// Single-level fine-tuning steps on real data after the chained ones.
    #[arg(long, value_parser = step_count)]
    finetune: Option<usize>,
    /// Save a checkpoint every N steps (0: never).
    #[arg(long, default_value_t = 100)]
    checkpoint_every: usize,
    /// Chains per step (1..=4096).
    #[arg(long, value_parser = batch_size)]
    batch: Option<usize>,
    /// Consecutive levels per chain (1..=5).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=5))]
    chain: Option<u32>,
    /// Adam learning rate, in (0, 1].
    #[arg(long, value_parser = learning_rate)]
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::World { region } => world(&region),
        Command::Export { region, spacing, format } => export(&region, spacing, format),
        Command::RangeField { seed, side, out } => range_field(seed, side as usize, &out),
        Command::Render { link, size, out, weights, threads, repeats } => render(&link, size, &out, weights, threads, repeats as usize),
        Command::Hillshade { input, spacing_m, side, out } => hillshade(&input, spacing_m, side as usize, &out),
        Command::Enhance { input, input_res, output_res, out, weights, batch } => enhance(&input, input_res, output_res, &out, weights, batch as usize),
        Command::TemProbe { weights } => tem_probe(weights),
        Command::TcmCalibrate { seeds, weights } => tcm_calibrate(seeds as u64, weights),
        Command::GrowCalibrate { seeds, weights } => grow_calibrate(seeds as u64, weights),
        Command::WorldBench { tiles, threads, gpu, weights } => world_bench(tiles, threads, gpu, weights),
        Command::TemExport { weights, out } => tem_export(weights, &out),
        Command::SketchExport { weights, out } => sketch_export(weights, &out),
        Command::SketchBench { repeats, threads, weights } => sketch_bench(repeats as usize, threads, weights),
        Command::HalfWeights { input, out } => half_weights(&input, &out),
        Command::AverageWeights { input, out } => average_weights(&input, &out),
        Command::TemBench { level, batch, repeats, threads, gpu, weights } => tem_bench(level as usize, batch as usize, repeats as usize, threads, gpu, weights),
        Command::TileBench { batches, repeats, threads, gpu, weights } => {
            tile_bench(if batches.is_empty() { &[1, 4, 16] } else { &batches }, repeats as usize, threads, gpu, weights)
        }
        #[cfg(feature = "train")]
        Command::TrainTem(a) => train_tem(a),
        Command::EvalSketch { pairs, weights, views, variants, extent_m } => eval_sketch(&pairs, weights, views.count as usize, variants as usize, extent_m),
        Command::Sketch { input, out, weights, views, format, relief, pow2_plus_1, extent_m } => {
            sketch(&input, &out, weights, views.count as usize, format.map(|f| (f, relief, pow2_plus_1)), extent_m)
        }
        Command::SketchExtract { dem, window, out, dem_out } => sketch_extract(&dem, &window, &out, dem_out),
        #[cfg(feature = "train")]
        Command::TrainSketch {
            dem_dir,
            steps,
            resume,
            checkpoint,
            checkpoint_every,
            batch,
            crop,
            pool,
            adversarial,
            validation,
            model,
            init,
            max_extent_m,
            min_extent_m,
            dems,
            hand_drawn,
            format_pairs,
            format_exclude,
            format_share,
            loss,
            lr,
            run,
            snapshots,
        } => {
            let format_share = if format_pairs.is_some() { format_share } else { 0.0 };
            let cfg = terrain::train::sketch::SketchConfig {
                batch: batch as usize,
                crop,
                pool: pool as usize,
                adversarial,
                windows: terrain::train::sketch::WindowChoice { dems, min_extent_m, max_extent_m, hand_drawn },
                format_pairs,
                format_exclude,
                format_share,
                lr,
                loss,
                ..Default::default()
            };
            train_sketch(&dem_dir, steps, resume, &checkpoint, checkpoint_every as usize, cfg, validation, model, init.as_deref(), &run, snapshots)
        }
        Command::SketchVariants { input, n, out_dir, seed, weights, views } => sketch_variants(&input, n as usize, &out_dir, seed, weights, views.count as usize),
        #[cfg(feature = "train")]
        Command::EvalTem { dem_dir, weights, windows } => eval_tem(dem_dir, weights, windows),
        #[cfg(feature = "train")]
        Command::EvalTcm { dem_dir, weights, seeds } => eval_tcm(&dem_dir, &weights, seeds),
        #[cfg(feature = "train")]
        Command::TrainTcm {
            dem_dir,
            steps,
            resume,
            checkpoint,
            checkpoint_every,
            batch,
            adversarial,
            init,
            ruggedness,
            drainage,
            coarse,
            free_l1,
            l1_reach,
            joined,
            dome,
            disc_slopes,
            coherence,
            position,
            macro_cells,
            mercator_dir,
            spacing_m,
            tcm_only,
            grow_only,
            grow_position,
            snapshots,
            run,
        } => train_tcm(
            match (&mercator_dir, &dem_dir) {
                (Some(d), _) => TcmData::Mercator(d, spacing_m),
                (None, Some(d)) => TcmData::Dems(d),
                (None, None) => unreachable!("clap requires --dem-dir without --mercator-dir"),
            },
            steps,
            resume,
            &checkpoint,
            checkpoint_every as usize,
            [batch as usize, macro_cells],
            [adversarial, ruggedness, drainage, coarse, free_l1, l1_reach, dome, coherence],
            [joined, disc_slopes],
            [position, grow_position],
            init.as_deref(),
            [tcm_only, grow_only, snapshots],
            &run,
        ),
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

/// A count of optimiser steps: a whole number up to 10⁹ (more would overflow step counters
/// long before it could run).
fn step_count(s: &str) -> Result<usize, String> {
    s.parse::<usize>().ok().filter(|n| *n <= 1_000_000_000).ok_or_else(|| format!("a step count is a whole number from 0 to 1000000000, not '{s}'"))
}

/// A sketch tile's ground extent: metres within [`terrain::models::sketch::EXTENT_RANGE_M`].
fn extent_metres(s: &str) -> Result<f64, String> {
    let (lo, hi) = terrain::models::sketch::EXTENT_RANGE_M;
    s.parse::<f64>().ok().filter(|m| (lo..=hi).contains(m)).ok_or_else(|| format!("a sketch's extent is {lo} to {hi} metres, not '{s}'"))
}

/// A sketch world's extent (`--extent-m` of `world --sketch`): metres across, within
/// [`terrain::world::sketched::EXTENT_M`].
fn sketch_world_extent(s: &str) -> Result<f64, String> {
    let range = terrain::world::sketched::EXTENT_M;
    s.parse::<f64>().ok().filter(|m| range.contains(m)).ok_or_else(|| format!("a sketch world is {} to {} metres across, not '{s}'", range.start(), range.end()))
}

/// A batch size: a whole number from 1 to 4096.
fn batch_size(s: &str) -> Result<usize, String> {
    s.parse::<usize>().ok().filter(|n| (1..=4096).contains(n)).ok_or_else(|| format!("a batch is a whole number from 1 to 4096, not '{s}'"))
}

/// A learning rate: a finite number above 0 and at most 1.
fn learning_rate(s: &str) -> Result<f64, String> {
    s.parse::<f64>().ok().filter(|r| r.is_finite() && *r > 0.0 && *r <= 1.0).ok_or_else(|| format!("a learning rate is a number above 0 and at most 1, not '{s}'"))
}
