//! The application core, independent of the browser: one world (seed + settings), the camera
//! and its controller, streaming and node selection per frame, and the statistics the overlay
//! and the tests read. The wasm shell feeds it input and draws what it returns.

use std::collections::VecDeque;
use std::sync::Arc;

use glam::DVec3;

pub mod coarse;
pub mod heightmap;
pub mod loads;
#[cfg(not(target_arch = "wasm32"))]
pub mod native;
pub mod page;
pub mod probe;
pub mod runners;
mod stats;

pub use stats::AppStats;

use crate::grid::mix64;
use crate::grid::schedule::tile_seed;
use crate::jobs::{Job, JobQueue, Outcome};
use crate::models::tem::LEVELS;
use crate::render::camera::{Camera, CameraController, ControlInput};
use crate::render::gpu::{FrameParams, sun_direction};
use crate::share::ShareState;
use crate::sketch::canvas::Canvas;
use crate::sketch::{SKETCH_PX, Sketch};
use crate::world::learned::{PIN_ERODED_REACH_TILES, PIN_REACH_TILES};
use crate::world::pins::Pins;
use crate::world::quadtree::{BASE_DATA_DEPTH, NodeCache, NodeData};
use crate::world::refine::{PatchKey, PatchStore, RefineJob};
use crate::world::sketched::SketchSource;
use crate::world::{ProceduralSource, SourceKind, TILE_SIZE_M, Tile, TileCoord, TileSource, WorldStream};

/// Milliseconds per frame that tile generation may use at least before it waits for the next
/// frame. When frames are slow for other reasons (a busy GPU), the budget grows to a quarter of
/// the median frame time, up to `TILE_BUDGET_MAX_MS`: the world streams in as fast as the
/// frame rate allows without lowering it.
pub const TILE_BUDGET_MS: f64 = 4.0;

/// Upper bound of the per-frame tile generation budget (milliseconds): with one tile over
/// the budget (~7 ms) and the node builds (≤ 15 ms measured), a frame's own work stays under
/// the page's 50 ms main-thread goal (at 40 ms the worst frame's tiles took 52 ms).
pub const TILE_BUDGET_MAX_MS: f64 = 25.0;

pub use crate::world::stream::TILE_JOBS_IN_FLIGHT;

/// Quadtree nodes built per frame at most (each is a 35² gather plus a mesh upload).
pub const NODE_BUILD_BUDGET: usize = 24;

/// Refined patches (quads) asked of the TEM per batch at most.
pub const REFINE_BATCH: usize = 4;

/// The sun's elevation (radians, 19°): a morning sun, low enough that ridges cast shadows
/// into the valleys beside them and the forms read from above.
pub const SUN_ELEVATION: f32 = 0.33;

/// Frames a node mesh stays on the GPU after it was last drawn.
pub const MESH_KEEP_FRAMES: u64 = 240;

/// Where the learned world's models are.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LearnedStatus {
    /// Their weights are loading: a learned world waits (no tiles yet).
    Loading,
    /// Ready; tiles are made by whoever takes [`TerrainApp::tile_jobs`]. The hash names the
    /// weights (share links carry it).
    Ready {
        /// Short hash of the weight files.
        hash: String,
    },
    /// They could not be loaded or run (the reason, for the user): the learned world is not
    /// available and the procedural world stands in.
    Failed(String),
}

/// The application state of one page.
pub struct TerrainApp {
    settings: ShareState,
    world: WorldStream,
    learned: LearnedStatus,
    /// Whether procedural tiles are made by whoever takes [`TerrainApp::tile_jobs`] (the page's
    /// CPU worker) instead of here, within each frame's time budget.
    procedural_elsewhere: bool,
    nodes: NodeCache,
    coarse_nodes: coarse::CoarseNodes,
    refine: PatchStore,
    refine_backend: Option<String>,
    /// The camera.
    pub camera: Camera,
    /// The camera controller.
    pub controller: CameraController,
    /// Tint nodes by quadtree depth.
    pub show_lod: bool,
    frame_ms: VecDeque<f64>,
    stats: AppStats,
    /// Most nodes a frame may draw (the GPU's mesh memory; unbounded without a GPU).
    node_budget: Option<usize>,
    /// The factor (≥ 1) the user's LOD target is raised by to keep the view within the node
    /// budget.
    lod_boost: f64,
    /// The nodes drawn in the last frame and where the eye was.
    last_nodes: (Vec<Arc<NodeData>>, DVec3),
    /// The previous world's picture and where the eye was: drawn instead of a new world until
    /// that world has made the tiles near the eye (a new seed never blanks the view).
    stand_in: Option<(Vec<Arc<NodeData>>, DVec3)>,
    time_s: f64,
    /// The sketch canvas (the sketch world shows its terrain).
    pub canvas: Canvas,
    sketch_models: LearnedStatus,
    /// Sketch → terrain jobs, keyed by canvas revision (one in flight: the latest stroke wins
    /// once it returns).
    sketch_jobs: JobQueue<u64>,
    /// A canvas revision whose terrain came back unusable: not asked for again until the
    /// canvas changes (else it would be asked for every frame).
    sketch_rejected: Option<u64>,
    /// The terrain of the sketch shown (0–255 scale), its canvas revision and the extent
    /// (metres across) it was made for.
    sketch_terrain: Option<(u64, Arc<Vec<f32>>, f64)>,
    /// The extent (metres across) the sketch job in flight was asked for.
    sketch_job_extent_m: f64,
    /// The canvas's code and the revision it was made at (share links).
    sketch_code: (u64, String),
    /// When (app time, seconds) the sketch last changed: a stroke, or its terrain shown.
    sketch_changed_s: f64,
    /// Terrain the user pinned into the learned world ([`set_user_pins`](Self::set_user_pins)).
    user_pins: Pins,
    /// The pins the world shown wants where its learned tiles are made, and their hash
    /// ([`worker_pins`](Self::worker_pins)): the sketch's tiles in the sketch world, else the
    /// user's.
    worker_pins: Arc<(String, Pins)>,
    /// The learned world's own tile (0, 0) of a seed, without pins: the ground a sketch in one
    /// tile is set into ([`SketchSource::with_base`], [`set_sketch_base`](Self::set_sketch_base)).
    sketch_base: Option<(u64, Arc<Vec<f32>>)>,
}

/// A camera pose that shows the whole sketch of `relief_m` and `extent_m` (metres across,
/// [`crate::world::sketched`]: an 8.2 km square centred on the origin, a smaller one in the
/// middle of tile (0, 0)) in world `seed` from the south, 35° down, about 0.63 extents from
/// its centre and 0.45 extents above its middle level (the square fills about 70 % of the
/// view's width at 16:10, nearer than the fog): position (metres), heading and pitch
/// (radians). The middle level is half the relief for an 8 km sketch (it stands on 0 m); for
/// one in a tile, whose outer samples' mean sits at the world's level there
/// ([`SketchSource::base_m`]), that level plus a quarter of the relief.
pub fn sketch_overview(relief_m: f64, extent_m: f64, seed: u64) -> ([f64; 3], f32, f32) {
    sketch_overview_over(relief_m, extent_m, crate::world::sketched::base_level_m(extent_m, seed) as f64)
}

/// [`sketch_overview`] of a sketch whose outer samples' mean stands at `level_m` metres (for
/// one set into the learned world's own tile, the ground's level around it:
/// [`SketchSource::with_base`]).
pub fn sketch_overview_over(relief_m: f64, extent_m: f64, level_m: f64) -> ([f64; 3], f32, f32) {
    use crate::world::sketched::{SKETCH_EXTENT_M, centre_m, clamp_extent_m, in_one_tile};
    let k = clamp_extent_m(extent_m) / SKETCH_EXTENT_M;
    let x = centre_m(extent_m) + 0.5 * crate::world::BASE_SPACING_M;
    let middle = level_m + if in_one_tile(extent_m) { 0.25 } else { 0.5 } * relief_m;
    ([x, middle + 3700.0 * k, x + 5200.0 * k], 0.0, -0.61)
}

/// Seconds the learned world around a sketch waits after the sketch last changed before its
/// tiles are asked for again: while the user draws, the worker makes strokes into terrain, not
/// the surroundings (which a stroke changes anyway), and the old ones stand in.
pub const SKETCH_SETTLE_S: f64 = 1.5;

/// Sketch → terrain jobs in flight at most.
pub const SKETCH_JOBS_IN_FLIGHT: usize = 1;

/// Height of the sea plane in the sketch world (metres): just below its plain at 0 m.
pub const SKETCH_SEA_M: f32 = -2.0;

impl TerrainApp {
    /// An app showing the world and view described by `s`.
    ///
    /// A learned world waits for [`set_learned`](Self::set_learned) (its models load
    /// elsewhere); until then it has no tiles.
    pub fn new(s: ShareState) -> Self {
        let learned = LearnedStatus::Loading;
        let world = Self::make_world(&s, &learned, None, false);
        let sketch = s.sketch.as_deref().and_then(|c| crate::sketch::code::decode(c).ok()).unwrap_or_else(|| crate::sketch::examples::first().1);
        let canvas = Canvas::new(sketch);
        let code = crate::sketch::code::encode(canvas.sketch());
        let mut app = Self {
            settings: s.clone(),
            world,
            learned,
            procedural_elsewhere: false,
            nodes: NodeCache::new(),
            coarse_nodes: Default::default(),
            refine: PatchStore::new(0, 0),
            refine_backend: None,
            camera: Camera::default(),
            controller: CameraController::default(),
            show_lod: false,
            frame_ms: VecDeque::new(),
            stats: AppStats::default(),
            node_budget: None,
            lod_boost: 1.0,
            last_nodes: (Vec::new(), DVec3::ZERO),
            stand_in: None,
            time_s: 0.0,
            canvas,
            sketch_models: LearnedStatus::Loading,
            sketch_jobs: JobQueue::new(SKETCH_JOBS_IN_FLIGHT),
            sketch_rejected: None,
            sketch_terrain: None,
            sketch_job_extent_m: crate::world::sketched::SKETCH_EXTENT_M,
            sketch_code: (0, code),
            sketch_changed_s: f64::NEG_INFINITY,
            user_pins: Pins::new(),
            worker_pins: Arc::new((String::new(), Pins::new())),
            sketch_base: None,
        };
        app.set_view(&s);
        app
    }

    fn make_world(s: &ShareState, learned: &LearnedStatus, sketch: Option<(&Arc<Vec<f32>>, f64)>, procedural_elsewhere: bool) -> WorldStream {
        match (s.source, learned) {
            // The sketch pinned into the learned world, which grows around it.
            (SourceKind::Sketch, LearnedStatus::Ready { hash }) if sketch.is_some() => {
                WorldStream::made_elsewhere(s.seed, format!("sketch in the learned world (TCM {hash})"), s.radius_tiles)
            }
            (SourceKind::Sketch, _) => match sketch {
                Some((h, extent_m)) => WorldStream::new(s.seed, Box::new(SketchSource::with_extent(h.clone(), s.relief_m, extent_m, s.seed)), s.radius_tiles),
                None => WorldStream::made_elsewhere(s.seed, "sketch (its terrain is being made…)".into(), s.radius_tiles),
            },
            (SourceKind::Learned, LearnedStatus::Ready { hash }) => WorldStream::made_elsewhere(s.seed, format!("learned (TCM {hash})"), s.radius_tiles),
            (SourceKind::Learned, LearnedStatus::Loading) => WorldStream::made_elsewhere(s.seed, "learned (loading its models…)".into(), s.radius_tiles),
            _ if procedural_elsewhere => WorldStream::made_elsewhere(s.seed, ProceduralSource::new(s.noise).name(), s.radius_tiles),
            _ => WorldStream::new(s.seed, Box::new(ProceduralSource::new(s.noise)), s.radius_tiles),
        }
    }

    /// The generator the world shown now really uses (the procedural world stands in for a
    /// learned one whose models failed).
    pub fn source(&self) -> SourceKind {
        match (self.settings.source, &self.learned) {
            (SourceKind::Learned, LearnedStatus::Failed(_)) => SourceKind::Procedural,
            (k, _) => k,
        }
    }

    /// The learned world's models are ready, loading or failed. A new status rebuilds a
    /// learned world (a failure shows the procedural one). Returns a note for the user when
    /// the view came from a link made with other weights than `hash` (the world may differ).
    pub fn set_learned(&mut self, status: LearnedStatus) -> Option<String> {
        if status == self.learned {
            return None;
        }
        self.learned = status;
        if self.settings.source != SourceKind::Procedural {
            self.new_world();
        }
        self.linked_weights_note()
    }

    /// A note for the user when the settings came from a link made with other weights than
    /// the ready models of the world they ask for (the learned world's or the sketch
    /// generator's): the world may differ from what the link's sender saw.
    pub fn linked_weights_note(&self) -> Option<String> {
        let (what, status) = match self.settings.source {
            SourceKind::Learned => ("learned-world", &self.learned),
            SourceKind::Sketch => ("sketch-generator", &self.sketch_models),
            SourceKind::Procedural => return None,
        };
        match (status, &self.settings.weights) {
            (LearnedStatus::Ready { hash }, Some(linked)) if linked != hash => {
                Some(format!("This link was made with {what} weights {linked}; this page has {hash}, so the world may differ."))
            }
            _ => None,
        }
    }

    /// The learned world's status.
    pub fn learned(&self) -> &LearnedStatus {
        &self.learned
    }

    /// Replaces the world with a fresh one for the current settings (new epoch): also when
    /// the learned world's pins changed where its tiles are made.
    pub fn new_world(&mut self) {
        self.new_world_from(0);
    }

    /// A fresh world whose epoch is at least `epoch`.
    fn new_world_from(&mut self, epoch: u64) {
        // Every new world gets a new epoch (after `epoch`): results of jobs (tiles, TEM
        // batches) made for an older one are dropped.
        let epoch = self.world.successor_epoch(epoch);
        let new = Self::make_world(&self.settings, &self.learned, self.sketch_terrain.as_ref().map(|t| (&t.1, t.2)), self.procedural_elsewhere).at_epoch(epoch);
        let old = std::mem::replace(&mut self.world, new);
        self.nodes = NodeCache::new();
        self.coarse_nodes.clear();
        let (last, at) = std::mem::take(&mut self.last_nodes);
        self.stand_in = (!last.is_empty()).then_some((last, at));
        let sketch = self.sketch_terrain.as_ref().filter(|_| self.settings.source == SourceKind::Sketch);
        let sketch = sketch.map(|(_, h, extent_m)| {
            let sketch = SketchSource::with_extent(h.clone(), self.settings.relief_m, *extent_m, self.settings.seed);
            match self.sketch_base.as_ref().filter(|b| b.0 == self.settings.seed && self.sketch_in_learned()) {
                Some((_, base)) => sketch.with_base(base.clone()),
                None => sketch,
            }
        });
        let pins = match sketch.as_ref().filter(|_| self.sketch_in_learned()) {
            Some(sketch) => {
                let pins = sketch.pins();
                self.take_over_sketch(old, sketch, &pins);
                // Its own tiles and the old ones stay drawn: no picture of the old world.
                self.stand_in = None;
                pins
            }
            None => self.user_pins.clone(),
        };
        // The user's terrain keeps its own detail where the TEM refines the learned world, and
        // a sketch finer than the world's 32 m its own (another world shown does not hold the
        // user's pins).
        let detail = match (self.source(), &sketch) {
            (SourceKind::Learned, _) => pins.clone(),
            (SourceKind::Sketch, Some(sketch)) if sketch.detail_level().is_some() => {
                if self.sketch_in_learned() {
                    pins.clone()
                } else {
                    sketch.pins()
                }
            }
            _ => Pins::new(),
        };
        self.refine = PatchStore::new(0, epoch).with_pins(detail, TileCoord::new(0, 0));
        if pins != self.worker_pins.1 {
            self.worker_pins = Arc::new((pins.hash(), pins));
        }
    }

    /// Whether the learned world around the sketch waits for the user to stop drawing: a
    /// stroke not yet made into terrain, a sketch job in flight, or the terrain shown less than
    /// [`SKETCH_SETTLE_S`] ago ([`tile_jobs`](Self::tile_jobs) and the coarse jobs ask for
    /// nothing meanwhile).
    fn sketch_unsettled(&self) -> bool {
        self.sketch_in_learned()
            && (self.sketch_jobs.stats().in_flight > 0
                || self.sketch_terrain.as_ref().is_some_and(|t| t.0 != self.canvas.revision() + 1 || t.2 != self.settings.extent_m)
                || self.time_s - self.sketch_changed_s < SKETCH_SETTLE_S)
    }

    /// The seed whose learned tile (0, 0) without pins the world shown waits for: a sketch in
    /// one tile pinned into the learned world is set into it ([`SketchSource::with_base`]);
    /// until it comes ([`set_sketch_base`](Self::set_sketch_base)) the sketch stands on a
    /// smooth foot.
    pub fn wants_sketch_base(&self) -> Option<u64> {
        let seed = self.settings.seed;
        let (_, _, extent_m) = self.sketch_terrain.as_ref().filter(|_| self.sketch_in_learned())?;
        let takes = crate::world::sketched::sets_into_tile(*extent_m);
        (takes && self.sketch_base.as_ref().is_none_or(|b| b.0 != seed)).then_some(seed)
    }

    /// The learned world's tile (0, 0) of `seed` without pins ([`TILE_SAMPLES`]² metres): a
    /// sketch in one tile is set into it from now on (the world is made again if it shows
    /// one, and a camera still where "Frame the sketch" put it, above the macro level, frames
    /// it again above the ground's own level). Heights of another size or not finite are
    /// refused.
    pub fn set_sketch_base(&mut self, seed: u64, heights: Vec<f32>) -> Result<(), String> {
        let n = crate::grid::TILE_SAMPLES;
        if heights.len() != n * n || heights.iter().any(|v| !v.is_finite()) {
            return Err(format!("the ground for the sketch is {} heights, not {} finite ones", heights.len(), n * n));
        }
        let shown = self.wants_sketch_base() == Some(seed);
        let framed = sketch_overview(self.settings.relief_m, self.settings.extent_m, seed).0;
        let still = self.camera.position_m == DVec3::from_array(framed);
        self.sketch_base = Some((seed, Arc::new(heights)));
        if shown {
            self.new_world();
            if still {
                self.frame_sketch();
            }
        }
        Ok(())
    }

    /// Whether the world shown is the sketch pinned into the learned world (the sketch world
    /// with its terrain here and the learned models ready).
    fn sketch_in_learned(&self) -> bool {
        self.settings.source == SourceKind::Sketch && matches!(self.learned, LearnedStatus::Ready { .. }) && self.sketch_terrain.is_some()
    }

    /// The new sketch-in-learned world takes over `old`'s tiles: the sketch's pinned tiles at
    /// once, the old tiles as stand-ins until the worker's arrive, and the fading plain of
    /// `sketch` around the pins where `old` had nothing, so the sketch is drawable at once. An
    /// old world that was the same learned world (same seed and weights) is the same beyond
    /// the reach of its pins and the sketch's (a sketch set into the world's own tile reaches
    /// no other tile): those tiles are kept as they are.
    fn take_over_sketch(&mut self, old: WorldStream, sketch: &SketchSource, pins: &Pins) {
        let same = old.seed() == self.world.seed() && old.source_name() == self.world.source_name();
        let tiles = sketch.tiles();
        let fixed = tiles.iter().map(|&c| Tile::new(c, pins.get(c).expect("a sketch pins the tiles it lies on").fine.to_vec())).collect();
        // Beyond the reach of the old world's pins too (an 8 km sketch before a small one).
        let old_pins = self.worker_pins.1.clone();
        let beyond = |c: TileCoord| !pins.within(c, PIN_REACH_TILES) && !old_pins.within(c, PIN_REACH_TILES);
        let coarse_beyond = |c: TileCoord| !pins.within(c, PIN_ERODED_REACH_TILES) && !old_pins.within(c, PIN_ERODED_REACH_TILES);
        self.world.take_over(old, fixed, same.then_some((&beyond as &dyn Fn(TileCoord) -> bool, &coarse_beyond as &dyn Fn(TileCoord) -> bool)));
        for c in tiles.iter().flat_map(|c| c.window3x3()) {
            if !self.world.contains(c) {
                self.world.insert_stale(sketch.tile(c));
            }
        }
    }

    /// The pins wherever the learned world's tiles are made for the world shown, with their
    /// hash ("" for none): the sketch's tiles in the sketch world, else the user's
    /// ([`set_user_pins`](Self::set_user_pins)). Whoever makes them must be given these
    /// before this world's tile jobs.
    pub fn worker_pins(&self) -> Arc<(String, Pins)> {
        self.worker_pins.clone()
    }

    /// The terrain the user pinned into the learned world.
    pub fn user_pins(&self) -> &Pins {
        &self.user_pins
    }

    /// Pins the user's terrain into the learned world (none: takes it out); a learned world
    /// shown is made again around them.
    pub fn set_user_pins(&mut self, pins: Pins) {
        self.user_pins = pins;
        if self.settings.source == SourceKind::Learned {
            self.new_world();
        }
    }

    /// Starts the world over at epoch `epoch` or later: a page that starts again (after a lost
    /// device) keeps the CPU worker, which drops requests of epochs older than the newest it
    /// has seen, so the new app's epochs must follow the old one's.
    pub fn continue_epochs_from(&mut self, epoch: u64) {
        self.new_world_from(epoch);
    }

    fn set_view(&mut self, s: &ShareState) {
        self.camera.position_m = DVec3::from_array(s.position_m);
        self.camera.yaw = s.yaw;
        self.camera.pitch = s.pitch;
    }

    /// Applies settings (and the view) from `s`: a new seed or noise rebuilds the world, a new
    /// radius resizes the cache; camera pose is taken over as is.
    pub fn apply(&mut self, s: ShareState) {
        let mut world_changed = s.seed != self.settings.seed || s.source != self.settings.source || s.noise != self.settings.noise || s.radius_tiles != self.settings.radius_tiles;
        world_changed |= s.source == SourceKind::Sketch && s.relief_m != self.settings.relief_m;
        // A new extent asks for a new terrain (sketch_jobs); the world follows when it comes.
        if let Some(sketch) = s.sketch.as_deref().filter(|c| *c != self.sketch_code.1).and_then(|c| crate::sketch::code::decode(c).ok()) {
            // A link with another sketch: draw it (undoable); its terrain follows as a job.
            self.canvas.load(sketch);
        }
        self.set_view(&s);
        self.settings = s;
        if world_changed {
            self.new_world();
        }
    }

    /// Applies settings from `s` but keeps the current camera pose (for the settings panel).
    pub fn apply_settings(&mut self, mut s: ShareState) {
        let now = self.share_state();
        s.position_m = now.position_m;
        s.yaw = now.yaw;
        s.pitch = now.pitch;
        if s.source == SourceKind::Sketch && now.source != SourceKind::Sketch {
            // Entering the sketch world: look at the sketch from the south.
            (s.position_m, s.yaw, s.pitch) = sketch_overview(s.relief_m, s.extent_m, s.seed);
        }
        if s.source != now.source {
            // Weights a link named belong to its world, not to the one chosen now.
            s.weights = None;
        }
        self.apply(s);
    }

    /// The view and settings as the user asked for them, for the address bar: the world
    /// source and weights they chose stay there while a stand-in (the procedural world for
    /// learned models that failed) is shown, so a reload asks for them again.
    pub fn asked_state(&self) -> ShareState {
        let now = self.share_state();
        let weights = if now.source == self.settings.source { now.weights.clone() } else { self.settings.weights.clone() };
        let sketch = if self.settings.source == SourceKind::Sketch { Some(self.sketch_code.1.clone()) } else { None };
        ShareState { source: self.settings.source, weights, sketch, ..now }
    }

    /// The current world, view and settings, as a share link carries them.
    /// It names the generator really used and, for the learned world, its weights.
    pub fn share_state(&self) -> ShareState {
        let source = self.source();
        let weights = match (&self.learned, &self.sketch_models, source) {
            (LearnedStatus::Ready { hash }, _, SourceKind::Learned) | (_, LearnedStatus::Ready { hash }, SourceKind::Sketch) => Some(hash.clone()),
            (_, _, SourceKind::Learned) => self.settings.weights.clone(),
            _ => None,
        };
        let sketch = (source == SourceKind::Sketch).then(|| self.sketch_code.1.clone());
        ShareState {
            position_m: self.camera.position_m.to_array(),
            yaw: self.camera.yaw,
            pitch: self.camera.pitch,
            source,
            weights,
            link_version: crate::share::LINK_VERSION,
            sketch,
            ..self.settings.clone()
        }
    }

    /// Whether procedural tiles are made elsewhere (`true`: by whoever takes
    /// [`tile_jobs`](Self::tile_jobs), e.g. the page's CPU worker, so the main thread never
    /// spends a frame on them) or here within each frame's budget (`false`, the default, and
    /// the fallback when the worker is gone). A change rebuilds a procedural world.
    pub fn set_procedural_elsewhere(&mut self, elsewhere: bool) {
        if elsewhere == self.procedural_elsewhere {
            return;
        }
        self.procedural_elsewhere = elsewhere;
        if self.source() == SourceKind::Procedural {
            self.new_world();
        }
    }

    /// The tiles to make now (nearest missing first, within [`TILE_JOBS_IN_FLIGHT`]): each
    /// must come back through [`tile_done`](Self::tile_done) or
    /// [`tile_failed`](Self::tile_failed). Empty unless the world is learned and its models are
    /// ready, or procedural and made elsewhere ([`set_procedural_elsewhere`](Self::set_procedural_elsewhere));
    /// the world's [`settings`](Self::settings) say which generator makes them.
    pub fn tile_jobs(&mut self) -> Vec<Job<TileCoord>> {
        if self.sketch_unsettled() {
            return Vec::new();
        }
        let learned_ready = self.learned_shown_ready();
        let procedural = self.source() == SourceKind::Procedural && self.procedural_elsewhere;
        if !learned_ready && !procedural {
            return Vec::new();
        }
        let eye = self.camera.position_m;
        self.world.start_jobs(eye.x, eye.z)
    }

    /// A tile came back: `heights` (metres, [`TILE_SAMPLES`]² row-major) made in `ms`
    /// milliseconds. Kept if it belongs to the world shown now; returns whether it was.
    pub fn tile_done(&mut self, job: &Job<TileCoord>, heights: Vec<f32>, ms: f64) -> bool {
        let replaces = self.world.is_stale(job.key);
        let kept = self.world.finish(job, heights, ms);
        if kept && replaces {
            // The nodes and refined patches made over the stand-in (and its neighbours' edges).
            let window = job.key.window3x3();
            self.nodes.retain_tiles(|t| !window.contains(&t));
            self.refine.retain_tiles(|t| !window.contains(&t));
        }
        kept
    }

    /// A tile could not be made: it may be asked for again.
    pub fn tile_failed(&mut self, job: &Job<TileCoord>) {
        self.world.fail(job);
    }

    /// The sketch generator is ready (its weights' hash), loading, or failed (then the sketch
    /// world shows the non-learned band interpolation, made here).
    /// Returns a note when the view came from a link made with other sketch weights.
    pub fn set_sketch_models(&mut self, status: LearnedStatus) -> Option<String> {
        self.sketch_models = status;
        self.linked_weights_note()
    }

    /// The sketch generator's status.
    pub fn sketch_models(&self) -> &LearnedStatus {
        &self.sketch_models
    }

    /// The sketch to turn into terrain now, if the canvas changed since the terrain shown and
    /// no job is in flight: it must come back through [`sketch_done`](Self::sketch_done) or
    /// [`sketch_failed`](Self::sketch_failed). With the generator failed, the band
    /// interpolation is made here at once instead.
    pub fn sketch_jobs(&mut self) -> Vec<(Job<u64>, Sketch)> {
        let (rev, extent_m) = (self.canvas.revision() + 1, self.settings.extent_m);
        if self.source() != SourceKind::Sketch || self.sketch_terrain.as_ref().is_some_and(|t| t.0 == rev && t.2 == extent_m) || self.sketch_rejected == Some(rev) {
            return Vec::new();
        }
        match &self.sketch_models {
            LearnedStatus::Ready { .. } => {
                let jobs: Vec<_> = self.sketch_jobs.start([rev]).into_iter().map(|j| (j, self.canvas.sketch().clone())).collect();
                if !jobs.is_empty() {
                    self.sketch_job_extent_m = extent_m;
                }
                jobs
            }
            LearnedStatus::Failed(_) => {
                let t = web_time::Instant::now();
                let h = crate::sketch::baseline::interpolate(self.canvas.sketch());
                self.show_sketch_terrain(rev, h, extent_m, t.elapsed().as_secs_f64() * 1e3);
                Vec::new()
            }
            LearnedStatus::Loading => Vec::new(),
        }
    }

    /// A sketch's terrain came back: `heights` ([`SKETCH_PX`]², 0–255 scale) made in `ms`.
    /// Shown unless a newer sketch's terrain already is; returns whether it was. Heights of
    /// the wrong count or not finite are refused with why, and that canvas revision is not
    /// asked for again until the canvas changes.
    pub fn sketch_done(&mut self, job: &Job<u64>, heights: Vec<f32>, ms: f64) -> Result<bool, String> {
        let bad = heights.iter().filter(|h| !h.is_finite()).count();
        if heights.len() != SKETCH_PX * SKETCH_PX || bad > 0 {
            self.sketch_jobs.fail(job);
            self.sketch_rejected = Some(job.key);
            return Err(format!("the generator returned {} heights, {bad} of them not finite numbers, for {}", heights.len(), SKETCH_PX * SKETCH_PX));
        }
        let extent_m = self.sketch_job_extent_m;
        // A terrain for the same canvas is shown again only when it was made for another
        // extent (the user changed it).
        if self.sketch_jobs.finish(job) == Outcome::Stale || self.sketch_terrain.as_ref().is_some_and(|t| t.0 > job.key || (t.0 == job.key && t.2 == extent_m)) {
            return Ok(false);
        }
        self.show_sketch_terrain(job.key, heights, extent_m, ms);
        Ok(true)
    }

    /// A sketch could not be made into terrain: it may be asked for again.
    pub fn sketch_failed(&mut self, job: &Job<u64>) {
        self.sketch_jobs.fail(job);
    }

    fn show_sketch_terrain(&mut self, rev: u64, heights: Vec<f32>, extent_m: f64, ms: f64) {
        self.sketch_terrain = Some((rev, Arc::new(heights), extent_m));
        self.sketch_changed_s = self.time_s;
        self.stats.sketch_ms = ms;
        self.stats.sketch_shown = rev;
        if self.settings.source == SourceKind::Sketch {
            self.new_world();
        }
    }

    /// The extent (metres across) the terrain of the sketch shown was made for, once there is
    /// one.
    pub fn sketch_terrain_extent_m(&self) -> Option<f64> {
        self.sketch_terrain.as_ref().map(|t| t.2)
    }

    /// The terrain of the sketch shown (0–255 scale, [`SKETCH_PX`]²), once there is one.
    pub fn sketch_terrain(&self) -> Option<&[f32]> {
        self.sketch_terrain.as_ref().map(|t| t.1.as_slice())
    }

    /// The settings in force (the camera pose in it is the one last applied).
    pub fn settings(&self) -> &ShareState {
        &self.settings
    }

    /// Name of the tile source.
    pub fn source_name(&self) -> String {
        self.world.source_name()
    }

    /// The epoch of the world shown now (see [`RefineJob::epoch`]).
    pub fn epoch(&self) -> u64 {
        self.world.epoch()
    }

    /// Current statistics.
    pub fn stats(&self) -> &AppStats {
        &self.stats
    }

    /// Records the duration (milliseconds) of the previous frame, keeping the last 2 seconds'
    /// worth (120 frames) for median and worst.
    pub fn record_frame_time(&mut self, ms: f64) {
        self.frame_ms.push_back(ms);
        while self.frame_ms.len() > 120 {
            self.frame_ms.pop_front();
        }
        let mut v: Vec<f64> = self.frame_ms.iter().copied().collect();
        v.sort_by(f64::total_cmp);
        self.stats.frame_ms_median = v[v.len() / 2];
        self.stats.frame_ms_worst = *v.last().unwrap_or(&0.0);
    }

    /// The tiles of the world shown that can be drawn around the eye now.
    pub fn drawable_tiles(&self) -> Vec<TileCoord> {
        let eye = self.camera.position_m;
        self.world.drawable(eye.x, eye.z)
    }

    /// The heights (metres) of tile `c` of the world shown, if it is cached.
    pub fn tile_heights(&self, c: TileCoord) -> Option<&[f32]> {
        self.world.get(c).map(|t| t.heights.as_slice())
    }

    /// Ground height (metres) under (x, z), where the tile is generated.
    pub fn ground_at(&self, x_m: f64, z_m: f64) -> Option<f32> {
        self.world.height_at(x_m, z_m)
    }

    /// Advances one frame of `dt_s` seconds: moves the camera (input, autopilot), streams
    /// tiles within the time budget, selects nodes for a viewport of `size_px` pixels and
    /// returns what to draw.
    pub fn frame(&mut self, input: &ControlInput, dt_s: f64, size_px: [u32; 2]) -> (Vec<Arc<NodeData>>, FrameParams) {
        let dt_s = dt_s.clamp(0.0, 0.25);
        self.time_s += dt_s;
        if self.sketch_code.0 != self.canvas.revision() {
            self.sketch_code = (self.canvas.revision(), crate::sketch::code::encode(self.canvas.sketch()));
        }
        self.stats.sketch_revision = self.canvas.revision() + 1;
        self.stats.sketch_jobs = self.sketch_jobs.stats();
        self.autopilot(dt_s);
        let world = &self.world;
        self.controller.update(&mut self.camera, input, dt_s, |x, z| world.height_at(x, z));

        let eye = self.camera.position_m;
        let budget = (self.stats.frame_ms_median * 0.25).clamp(TILE_BUDGET_MS, TILE_BUDGET_MAX_MS);
        let t0 = web_time::Instant::now();
        self.world.update(eye.x, eye.z, budget);
        let t1 = web_time::Instant::now();
        let world = &self.world;
        self.nodes.retain_tiles(|t| world.contains(t));
        self.refine.retain_tiles(|t| world.contains(t));
        let tiles = self.world.drawable(eye.x, eye.z);
        // The far ring once a frame: it is a sort of a few hundred tiles.
        let ring = self.world.far_ring(eye.x, eye.z);
        self.make_local_far_field(&ring);
        self.camera.far_m = self.view_far_m();
        let aspect = size_px[0].max(1) as f32 / size_px[1].max(1) as f32;
        let refining = self.refine_backend.is_some();
        let max_depth = if refining { BASE_DATA_DEPTH + LEVELS as u8 } else { BASE_DATA_DEPTH };
        let lod_px = self.settings.lod_px * self.lod_boost;
        let view = self.camera.lod_view(aspect, size_px[1].max(1) as f32, lod_px, max_depth);
        let mut budget = NODE_BUILD_BUDGET;
        let refine = if refining { Some(&mut self.refine) } else { None };
        let mut nodes = self.nodes.select(&tiles, &self.world, refine, &view, &mut budget);
        let shown = self.add_coarse(&mut nodes, &tiles, &ring, &view);
        self.fit_node_budget(nodes.len());
        let nodes = self.or_stand_in(nodes, &shown);
        self.stats.lod_px_effective = lod_px;
        self.stats.node_budget = self.node_budget;
        self.stats.world_ms = (t1 - t0).as_secs_f64() * 1e3;
        self.stats.nodes_ms = t1.elapsed().as_secs_f64() * 1e3;

        let ws = self.world.stats();
        self.stats.frames += 1;
        self.stats.tiles_generated = ws.generated;
        self.stats.tiles_cached = ws.cached;
        self.stats.tiles_capacity = self.world.capacity();
        self.stats.tiles_pending = ws.pending;
        self.stats.tiles_uncovered = ws.uncovered;
        self.stats.tiles_evicted = ws.evicted;
        self.stats.ms_per_tile = ws.ms_per_tile();
        self.stats.nodes_drawn = nodes.len();
        self.stats.nodes_cached = self.nodes.len();
        self.stats.max_depth_drawn = nodes.iter().map(|n| n.id.depth).max().unwrap_or(0);
        let rs = self.refine.stats();
        self.stats.quads_made = rs.quads_made;
        self.stats.ms_per_quad = rs.ms_per_quad();
        self.stats.patches_cached = rs.cached;
        self.stats.refine_backend = self.refine_backend.clone().unwrap_or_default();
        self.stats.source = self.source().label().into();
        self.stats.tile_jobs = self.world.job_stats();
        self.stats.tiles_stale = ws.pending - ws.uncovered;
        self.stats.eye_m = eye.to_array();
        let sum = tiles.iter().filter_map(|&c| self.world.get(c)).fold(0u64, |acc, t| acc.wrapping_add(mix64(t.checksum ^ tile_seed(0, t.coord))));
        self.stats.view_checksum = format!("{sum:016x}");

        let n = &self.settings.noise;
        let (fog_start_m, fog_end_m) = self.fog_m();
        let params = FrameParams {
            camera: self.camera,
            size: size_px,
            sun_dir: sun_direction(2.3, SUN_ELEVATION),
            fog_start_m,
            fog_end_m,
            // The sketch's plain lies at 0 m and is drawn as water by the terrain itself (level
            // ground); the sea plane goes below it so the two do not fight.
            water_level_m: if self.source() == SourceKind::Sketch { SKETCH_SEA_M } else { 0.0 },
            amplitude_m: match self.source() {
                SourceKind::Learned => crate::world::ranges::TOP_M,
                SourceKind::Procedural => (n.amplitude_m + n.base_m).max(100.0),
                SourceKind::Sketch if self.sketch_in_learned() => (self.settings.relief_m as f32).max(crate::world::ranges::TOP_M),
                SourceKind::Sketch => self.settings.relief_m as f32,
            },
            show_lod: self.show_lod,
            time_s: self.time_s as f32,
            plain_shading: self.settings.plain_shading,
        };
        (nodes, params)
    }

    /// `nodes` of the world shown, or the previous world's picture while this world has
    /// neither made nor a coarse stand-in for each tile within a tile of the eye (in view or
    /// not) and the eye stayed within a tile of where that picture was taken ([`SourceKind`]
    /// or seed changed in place). `tiles` are this world's drawable tiles.
    fn or_stand_in(&mut self, nodes: Vec<Arc<NodeData>>, tiles: &[TileCoord]) -> Vec<Arc<NodeData>> {
        let eye = self.camera.position_m;
        let near_made = || {
            let near = self.world.wanted(eye.x, eye.z).into_iter().filter(|c| c.distance_tiles(eye.x, eye.z) <= 1.0f64.min(self.world.radius_tiles()));
            near.into_iter().all(|c| tiles.contains(&c) || self.world.coarse(c).is_some())
        };
        let keep = match &self.stand_in {
            Some((_, at)) => (eye - *at).length() < TILE_SIZE_M && !near_made(),
            None => false,
        };
        if !keep {
            self.stand_in = None;
        }
        self.stats.previous_world_shown = keep;
        let drawn = match (&self.stand_in, keep) {
            (Some((old, _)), true) => old.clone(),
            _ => nodes,
        };
        self.last_nodes = (drawn.clone(), eye);
        drawn
    }

    /// Most nodes a frame may draw on the GPU the view is drawn with
    /// ([`crate::render::node_budget`]).
    pub fn set_node_budget(&mut self, nodes: usize) {
        self.node_budget = Some(nodes.max(1));
    }

    /// Raises the LOD target by a quarter while the view selected with it has more nodes
    /// than the budget (up to the coarsest target a link may ask for), and lowers it again by
    /// a tenth (never below the user's) while it has fewer than 60 % of them. Each step
    /// changes the node count by less than the band between the two, so it settles.
    fn fit_node_budget(&mut self, nodes: usize) {
        let Some(budget) = self.node_budget else { return };
        let most = crate::share::LOD_PX.end() / self.settings.lod_px;
        if nodes > budget {
            self.lod_boost = (self.lod_boost * 1.25).min(most.max(1.0));
        } else if (nodes as f64) < 0.6 * budget as f64 {
            self.lod_boost = (self.lod_boost / 1.1).max(1.0);
        }
    }

    /// Turns learned refinement on (TEM models ready; `backend` names where they run, for the
    /// overlay) or off (`None`).
    pub fn set_refinement(&mut self, backend: Option<String>) {
        if backend.is_none() {
            self.nodes.retain_depth(BASE_DATA_DEPTH);
        }
        self.refine_backend = backend;
    }

    /// The TEM jobs this frame asks for (at most `max`, one level, nearest first); each must
    /// come back through [`refine_done`](Self::refine_done) or
    /// [`refine_failed`](Self::refine_failed).
    pub fn refine_jobs(&mut self, max: usize) -> Vec<RefineJob> {
        if self.refine_backend.is_none() {
            return Vec::new();
        }
        self.refine.next_jobs(&self.world, max)
    }

    /// Stores the results of a batch made for world `epoch`: `raw` is the models' output for
    /// `keys` in order ((2·INPUT_SIDE)² metres each), `ms` the batch's time. A batch of an
    /// older world (the seed, noise or radius changed while it ran) is dropped whole. A batch
    /// of the wrong size or with a height that is not finite is dropped (its patches may be
    /// asked for again) and the error says so.
    pub fn refine_done(&mut self, epoch: u64, keys: &[PatchKey], raw: &[f32], ms: f64) -> Result<(), String> {
        let world = &self.world;
        self.refine.complete_batch(epoch, keys, raw, ms, |t| world.contains(t)).map(|_| ())
    }

    /// Forgets jobs of world `epoch` whose inference failed, so they can be asked for again.
    pub fn refine_failed(&mut self, epoch: u64, keys: &[PatchKey]) {
        if epoch == self.epoch() {
            self.refine.abandon(keys);
        }
    }

    /// Counters of the learned refinement of the current world.
    pub fn refine_stats(&self) -> crate::world::RefineStats {
        self.refine.stats()
    }

    /// Runs up to `max` TEM jobs now on `tem` (blocking; native) and stores them through
    /// [`PatchStore::complete_batch`], the completion path the page's batches take too.
    /// Returns how many patches were made.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn refine_blocking(&mut self, tem: &crate::models::tem::TemSet, max: usize) -> Result<usize, String> {
        if self.refine_backend.is_none() {
            return Ok(0);
        }
        let jobs = self.refine.next_jobs(&self.world, max);
        let world = &self.world;
        crate::world::refine::run_blocking(&mut self.refine, tem, jobs, |t| world.contains(t))
    }

    /// The 32 m heights of the largest square of whole tiles around the eye that the world
    /// has made (at most the relevance radius), for export; `None` before the eye's tile.
    pub fn export_view(&self) -> Option<crate::dem::Heightfield> {
        let eye = self.camera.position_m;
        crate::world::export::around(&self.world, eye.x, eye.z, self.settings.radius_tiles.floor() as u32)
    }

    /// The view's learned detail at TEM level `level` (16, 8, 4, 2 or 1 m) around the eye, what
    /// the page exports at that spacing ([`PatchStore::export_around`]), or what to tell the
    /// user when none is refined there yet.
    pub fn export_refined(&self, level: usize) -> Result<crate::dem::Heightfield, String> {
        let s = crate::models::tem::LEVEL_SPACING_M.get(level).ok_or_else(|| format!("the learned detail has levels 0 to {}, not {level}", LEVELS - 1))?;
        if self.refine_backend.is_none() {
            return Err(format!("Nothing is refined to {s} m: learned detail is off (switch it on in the overlay)."));
        }
        let eye = self.camera.position_m;
        self.refine
            .export_around(level, eye.x, eye.z)
            .ok_or_else(|| format!("Nothing is refined to {s} m yet: fly lower over rough ground until the view shows that detail, then export."))
    }

    /// Puts the camera where it shows the whole sketch ([`sketch_overview`]), above the
    /// ground's level around it where it is set into the learned world's own tile.
    pub fn frame_sketch(&mut self) {
        let s = &self.settings;
        let set_in = self.sketch_terrain.as_ref().filter(|t| t.2 == s.extent_m).zip(self.sketch_base.as_ref().filter(|b| b.0 == s.seed));
        let level = match set_in {
            Some((t, b)) => SketchSource::with_extent(t.1.clone(), s.relief_m, t.2, s.seed).with_base(b.1.clone()).base_m(),
            None => crate::world::sketched::base_level_m(s.extent_m, s.seed),
        };
        let (p, yaw, pitch) = sketch_overview_over(s.relief_m, s.extent_m, level as f64);
        (self.camera.position_m, self.camera.yaw, self.camera.pitch) = (DVec3::from_array(p), yaw, pitch);
        if self.controller.mode == crate::render::CameraMode::Orbit {
            self.set_camera_mode(crate::render::CameraMode::Fly);
            self.set_camera_mode(crate::render::CameraMode::Orbit);
        }
    }

    /// Switches between flying and orbiting without moving the camera: the orbit's pivot is the
    /// terrain under the screen's centre.
    pub fn set_camera_mode(&mut self, mode: crate::render::CameraMode) {
        let world = &self.world;
        self.controller.set_mode(mode, &self.camera, |x, z| world.height_at(x, z));
    }

    /// Autopilot: fly level along the heading at the link's speed, following the terrain
    /// 400 m above the highest ground within the next kilometre.
    fn autopilot(&mut self, dt_s: f64) {
        let v = self.settings.autopilot_mps;
        if v <= 0.0 {
            return;
        }
        let (s, c) = (self.camera.yaw as f64).sin_cos();
        let dir = DVec3::new(s, 0.0, -c);
        self.camera.position_m += dir * v * dt_s;
        let p = self.camera.position_m;
        let ahead = (0..=4).filter_map(|k| self.world.height_at(p.x + dir.x * 250.0 * k as f64, p.z + dir.z * 250.0 * k as f64)).fold(f32::NEG_INFINITY, f32::max);
        if ahead.is_finite() {
            let target = ahead as f64 + 400.0;
            let blend = (dt_s * 1.5).min(1.0);
            self.camera.position_m.y += (target - p.y) * blend;
        }
    }
}

#[cfg(test)]
mod tests;
