//! The page's core: every load and every piece of work in flight, platform-free. The shell
//! only carries out what [`PageCore::take_effects`] asks (fetch a URL; post a request to the
//! CPU worker, the main thread or the GPU) and hands back what came of it with one
//! [`PageCore::deliver`]. Every request has an id in one table of work in flight that says
//! what it was for (a file of a model set, a load, a tile, a TEM batch, a sketch, variants, a
//! blend), so each reply goes one way back into the app, and a runner that dies fails exactly
//! the requests it held.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

use glam::DVec3;

use super::heightmap::{PendingPng, PngKind};
use super::loads::{Load, LoadError, Loads, ModelSet, notice, reason};
use super::probe::{Probe, SKETCH_TIMED_RUNS, TIMED_RUNS};
use super::{LearnedStatus, REFINE_BATCH, TerrainApp};
use crate::grid::TileCoord;
use crate::jobs::protocol::{Answer, Envelope, Reply, Request, SketchBytes};
use crate::jobs::{Job, JobQueue, Outcome};
use crate::models::runtime::{self, Backend, CpuReason, TemChoice};
use crate::models::tem::{PROBE_SIDE, probe_input};
use crate::share::ShareState;
use crate::share::bundle::WorldBundle;
use crate::sketch::{SKETCH_PX, Sketch};
use crate::world::learned::{NetworkWork, WorkKeys};
use crate::world::pins::Pins;
use crate::world::refine::INPUT_SIDE;
use crate::world::{PatchKey, SourceKind};

/// Largest GeoTIFF or PNG read for a pin (bytes): a 4096² float32 grid and its tags.
pub const MAX_PIN_FILE_BYTES: f64 = 65.0 * 1024.0 * 1024.0;

/// Who runs a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// The CPU worker (a Web Worker; natively a thread).
    Worker,
    /// The CPU kernels on the main thread (no worker: they block frames, so rationed).
    MainThread,
    /// burn on the shared GPU device.
    Gpu,
}

/// What the core asks the shell to do.
#[derive(Debug)]
pub enum Effect {
    /// Download `url` and deliver [`Delivery::Fetched`] with `id`.
    Fetch {
        /// The request's id.
        id: u32,
        /// The URL (relative to the page).
        url: String,
    },
    /// Hand `envelope` to `target` and deliver its [`Answer`].
    Post {
        /// Who runs it.
        target: Target,
        /// The request.
        envelope: Envelope,
    },
}

/// What comes back to the core.
#[derive(Debug)]
pub enum Delivery {
    /// The bytes of a fetch, or why it failed.
    Fetched {
        /// The fetch's id.
        id: u32,
        /// The body or the reason.
        bytes: Result<Vec<u8>, String>,
    },
    /// A runner's answer.
    Answer(Answer),
    /// The CPU worker could not take request `id` because it is gone (why): every request it
    /// held fails, and its work moves to the fallbacks.
    WorkerGone {
        /// The request it could not answer.
        id: u32,
        /// The browser's reason.
        why: String,
    },
}

/// What a request in flight is for.
#[derive(Debug)]
enum For {
    /// File `index` of `set`, on its `attempt`-th download (1 = the first).
    File {
        set: ModelSet,
        index: usize,
        attempt: usize,
    },
    Load {
        set: ModelSet,
        target: Target,
    },
    /// A tile made by the worker, and the milliseconds its network work took elsewhere
    /// (the GPU) before.
    Tile(Job<TileCoord>, f64),
    Coarse(Job<TileCoord>),
    /// The worker's next batch of network work for a tile whose networks run on the GPU.
    WorldWork(Chain),
    /// That batch on the GPU, a call of a few of its items at a time.
    RunWork(Chain, GpuBatch),
    /// Its outputs, kept by the worker.
    AcceptWork(Chain),
    /// A run of the world networks' probe on this backend.
    WorldProbeRun(Target),
    /// The probe's load of the TEM on the backend it does not run on yet.
    ProbeLoad(Target),
    /// A probe quad on this backend.
    ProbeRun(Target),
    /// A probe sketch on this backend.
    SketchProbeRun(Target),
    Tem {
        epoch: u64,
        keys: Vec<PatchKey>,
    },
    Sketch(Job<u64>, Target),
    Variants(Job<SketchEdit>),
    Blend(Job<SketchEdit>),
    /// Pins sent to the worker (their file's name).
    Pin(String),
    /// The learned world's tile (0, 0) of this seed without pins, for a small sketch's ground.
    SketchBase(u64),
}

/// A learned tile (or the far field's eroded 128 m tile) whose network work runs on the GPU:
/// the worker hands out each batch ([`Request::WorldWork`]), the GPU runs it
/// ([`Request::RunWork`]), the worker keeps the outputs ([`Request::AcceptWork`]), until none is
/// left and the worker makes the tile from them ([`Request::Tile`], [`Request::Coarse`]). One
/// chain runs at a time, so no batch is run twice for two tiles that share it.
#[derive(Debug)]
struct Chain {
    job: Job<TileCoord>,
    /// The far field's eroded 128 m tile, not the 32 m tile.
    coarse: bool,
    /// The seed of the job's world.
    seed: u64,
    /// Milliseconds its batches took on the GPU so far.
    net_ms: f64,
}

/// A batch of network work from the worker on its way through the GPU, a few items a call
/// ([`PageCore::gpu_call_items`]) so that a frame never waits long behind it; the outputs are
/// gathered for the worker in one accept-work.
#[derive(Debug)]
struct GpuBatch {
    /// The whole batch's kind and tiles.
    keys: WorkKeys,
    /// Its items not sent to the GPU yet.
    rest: NetworkWork,
    /// The outputs of the calls answered so far, in order.
    outputs: Vec<Vec<f32>>,
    /// Milliseconds those calls took.
    ms: f64,
}

impl For {
    /// Whether this is a step of a [`Chain`].
    fn is_chain(&self) -> bool {
        matches!(self, For::WorldWork(_) | For::RunWork(..) | For::AcceptWork(_))
    }
}

/// TCM tiles in the world networks' probe batch ([`NetworkWork::probe`]): a phase of the
/// schedule hands out 16 to 40.
pub const WORLD_PROBE_TILES: usize = 16;

/// How long one call of the world's network work on the GPU may take, in median frames: a
/// batch is sent a few items a call ([`PageCore::gpu_call_items`]), so a frame waits behind at
/// most about one call. On a software adapter (SwiftShader) a batch of 40 TCM tiles in one call
/// held the page's frames for 21–26 s. Less than one: the frames a call slows down make the
/// median longer, and at a whole frame each call would be allowed more items than the last
/// without bound; at half, calls settle where they take as long as the rest of a frame.
pub const GPU_CALL_FRAMES: f64 = 0.5;

/// One run of the world networks' probe, as its timings name it: "batch of 16 tiles".
pub fn world_probe_unit() -> String {
    format!("batch of {WORLD_PROBE_TILES} tiles")
}

/// An edit of the canvas's sketch made by the sketch VAE: at most one of each in flight.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum SketchEdit {
    Variants,
    Blend,
}

/// What the shell found when the page started.
#[derive(Clone, Debug)]
pub struct PageStart {
    /// Where the user wants the TEM (`?tem=`).
    pub tem: TemChoice,
    /// Where the user wants the learned world's networks (`?world=`).
    pub world: TemChoice,
    /// The GPU's self-check: passed, or why burn cannot use it.
    pub gpu: Result<(), String>,
    /// Whether the WebGPU adapter is a software rasteriser.
    pub software_adapter: bool,
    /// The CPU worker started, or why not.
    pub worker: Result<(), String>,
    /// The overlay's line about the GPU runtime (the self-check's result).
    pub status: String,
}

/// How long a request to the CPU worker may go unanswered (ms) before the worker is taken for
/// stalled. Its slowest requests (a learned tile beside a software rasteriser, a load, four
/// variants) take a few seconds.
pub const WORKER_TIMEOUT_MS: f64 = 60_000.0;

/// How long a weight file's failed download waits before it is tried again (ms), per failed
/// attempt: a dropped connection or a server's hiccup costs the user a second or three, not the
/// learned world. After the last, the set fails and its fallback is said.
pub const FETCH_RETRY_MS: [f64; 2] = [1_000.0, 3_000.0];

/// Ids are unique in the whole page, across restarts of the core after a lost device, so a
/// late reply for an old core never matches a new request.
static NEXT_ID: AtomicU32 = AtomicU32::new(1);

/// Epochs handed to each core of the page: each new core's worlds start after every earlier
/// core's (a core restarted after a lost device keeps the worker, which drops older epochs).
static EPOCH_BLOCKS: AtomicU64 = AtomicU64::new(0);

/// What the page says after a panic on its main thread: that it stopped and why (the first
/// 300 characters), and that the view is kept in the address bar.
pub fn stopped_message(why: &str) -> String {
    let why: String = why.chars().take(300).collect();
    format!("The page stopped because of an error: {why}. Your view is kept in the address bar; reload to go on.")
}

/// A new request id (unique in the page).
pub fn next_id() -> u32 {
    NEXT_ID.fetch_add(1, Ordering::Relaxed).max(1)
}

/// What a page started again after a lost device keeps of the old one.
#[derive(Clone, Debug)]
pub struct Kept {
    /// The view and settings.
    pub share: ShareState,
    /// What to tell the user.
    pub note: String,
    /// The terrain pinned into the learned world, and its file's name.
    pub pinned: Option<(String, Pins)>,
}

/// The page's core (see the module documentation).
pub struct PageCore {
    /// The world, camera and sketch canvas.
    pub app: TerrainApp,
    /// The model loads.
    pub loads: Loads,
    /// A message for the user (dismissable), if any.
    pub message: Option<String>,
    /// The overlay's line about the GPU runtime.
    pub status: String,
    /// Learned detail is switched on (the overlay's switch; off with `?tem=off`).
    pub refine_on: bool,
    /// Variants that came back, for the sketch panel to take.
    pub variants: Option<Vec<(Sketch, Vec<f32>)>>,
    /// Blends that came back and were drawn.
    pub blends: u32,
    /// Notes for the browser console (a GPU path that fell back to the CPU).
    pub console: Vec<String>,
    /// Your terrain pinned into the learned world ([`Self::pin_dem`]): its file's name and
    /// tiles.
    pub pinned: Option<(String, usize)>,
    effects: Vec<Effect>,
    waiting: HashMap<u32, For>,
    /// When each request to the CPU worker was posted (page clock, ms).
    sent: HashMap<u32, f64>,
    /// The page clock at the last [`PageCore::start_work`] (ms).
    now_ms: f64,
    files: HashMap<ModelSet, Vec<Option<Vec<u8>>>>,
    /// Downloads to try again: (page clock when due, ms; set; file index; the attempt it will be).
    refetch: Vec<(f64, ModelSet, usize, usize)>,
    tem: Backend,
    tem_target: Target,
    /// What the user asked for (`?tem=`) and the GPU's self-check: the probe's choice keeps to
    /// them.
    tem_choice: TemChoice,
    gpu: Result<(), String>,
    /// The start-up probe ([`super::probe`]) and, until it starts, the TEM's files for its
    /// second load.
    probe: Probe,
    probe_files: Option<Vec<Vec<u8>>>,
    /// The sketch generator's probe ([`super::probe`]).
    sketch_probe: Probe,
    /// The sketch generator has loaded on the GPU.
    sketch_gpu_loaded: bool,
    sketch_on_gpu: bool,
    worker: Result<(), String>,
    software_adapter: bool,
    complete_epoch: Option<u64>,
    rest_per_work: f64,
    last_eye: Option<(DVec3, f64)>,
    last_main_quad_ms: f64,
    pending_blend: Option<(Sketch, Sketch, f32)>,
    /// The variants and the blend in flight.
    edits: JobQueue<SketchEdit>,
    /// The fragment in the address bar as last read or written, and when it was written.
    link: (String, f64),
    /// The hash of the pins the CPU worker's learned world has (`None` before it has one).
    pins_sent: Option<String>,
    /// The seed whose unpinned tile (0, 0) was last asked of the worker for a sketch's ground
    /// ([`crate::app::TerrainApp::wants_sketch_base`]).
    base_asked: Option<u64>,
    /// Where the user wants the learned world's networks (`?world=`).
    world_choice: TemChoice,
    /// Where they run once they have loaded there (the probe may change it).
    world_nets: Backend,
    /// The world's networks on the GPU: not loaded (yet), loaded, or why they cannot run there.
    world_gpu: Option<Result<(), String>>,
    /// The world networks' start-up probe ([`super::probe`]).
    world_probe: Probe,
    /// Tiles waiting for their network work to run on the GPU, one [`Chain`] at a time.
    chains: VecDeque<Chain>,
    /// Milliseconds of network work run on the GPU for 32 m tiles, and those tiles.
    world_gpu_ms: (f64, usize),
    /// Milliseconds an item of the world's network work took in the GPU's last call (or the
    /// probe's), if one was timed.
    world_gpu_item_ms: Option<f64>,
    /// A heightmap PNG the user opened, waiting for its spacing and heights.
    pub heightmap: Option<PendingPng>,
    /// JSON sidecars the user opened (name, contents), the latest four, for a heightmap PNG
    /// that comes after them.
    sidecars: Vec<(String, serde_json::Value)>,
}

impl PageCore {
    /// The core of a page showing `share`, with what the shell found; asks at once for the
    /// learned world's and the TEM's weights (the sketch models when the sketch world is first
    /// shown).
    pub fn new(share: ShareState, start: PageStart) -> Self {
        let tem = runtime::choose(start.tem, start.gpu.clone(), start.software_adapter);
        let probe = if runtime::probe_wanted(start.tem, start.gpu.is_ok(), start.worker.is_ok(), start.software_adapter) { Probe::Waiting } else { Probe::Off };
        let tem_target = match (&tem, &start.worker) {
            (Backend::Gpu, _) => Target::Gpu,
            (_, Ok(())) => Target::Worker,
            (_, Err(_)) => Target::MainThread,
        };
        let status = match &tem {
            Backend::Cpu(CpuReason::NoGpuCompute(e)) => format!("{e}; the TEM runs on the CPU"),
            _ => start.status,
        };
        let world_probe = if runtime::probe_wanted(start.world, start.gpu.is_ok(), start.worker.is_ok(), start.software_adapter) { Probe::Waiting } else { Probe::Off };
        let mut app = TerrainApp::new(share);
        app.continue_epochs_from(EPOCH_BLOCKS.fetch_add(1, Ordering::Relaxed) << 32);
        let mut core = Self {
            app,
            loads: Loads::default(),
            message: None,
            status,
            refine_on: start.tem != TemChoice::Off,
            variants: None,
            blends: 0,
            console: Vec::new(),
            pinned: None,
            effects: Vec::new(),
            waiting: HashMap::new(),
            sent: HashMap::new(),
            now_ms: 0.0,
            files: HashMap::new(),
            refetch: Vec::new(),
            tem,
            tem_target,
            tem_choice: start.tem,
            gpu: start.gpu.clone(),
            probe: probe.clone(),
            probe_files: None,
            sketch_probe: probe,
            sketch_gpu_loaded: false,
            sketch_on_gpu: false,
            worker: start.worker,
            software_adapter: start.software_adapter,
            complete_epoch: None,
            rest_per_work: 0.0,
            last_eye: None,
            last_main_quad_ms: f64::NEG_INFINITY,
            pending_blend: None,
            edits: JobQueue::new(2),
            link: (String::new(), f64::NEG_INFINITY),
            pins_sent: None,
            base_asked: None,
            world_choice: start.world,
            world_nets: runtime::choose(start.world, start.gpu.clone(), start.software_adapter),
            world_gpu: None,
            world_probe,
            chains: VecDeque::new(),
            world_gpu_ms: (0.0, 0),
            world_gpu_item_ms: None,
            heightmap: None,
            sidecars: Vec::new(),
        };
        if let Err(why) = core.worker.clone() {
            core.fail(ModelSet::World, &LoadError::NoWorker(why));
        } else {
            core.fetch(ModelSet::World);
        }
        core.fetch(ModelSet::Tem);
        core
    }

    /// What the shell is to do now (oldest first).
    pub fn take_effects(&mut self) -> Vec<Effect> {
        std::mem::take(&mut self.effects)
    }

    /// Requests in flight now.
    pub fn in_flight(&self) -> usize {
        self.waiting.len()
    }

    /// Where the TEM runs (the overlay's name, e.g. "WebGPU", "CPU (software WebGPU adapter)").
    pub fn tem_backend(&self) -> String {
        match self.tem_target {
            Target::MainThread => format!("{} on the main thread", self.tem.label()),
            _ => self.tem.label(),
        }
    }

    /// Who runs the TEM.
    pub fn tem_target(&self) -> Target {
        self.tem_target
    }

    /// Where strokes become terrain ("WebGPU" or "CPU worker").
    pub fn sketch_backend(&self) -> &'static str {
        if self.sketch_on_gpu { "WebGPU" } else { "CPU worker" }
    }

    /// The CPU worker's rest per ms of work in the last frame
    /// ([`runtime::worker_rest_per_work`]).
    pub fn rest_per_work(&self) -> f64 {
        self.rest_per_work
    }

    /// The worker is up (or why not).
    pub fn worker(&self) -> &Result<(), String> {
        &self.worker
    }

    fn fetch(&mut self, set: ModelSet) {
        let files = set.files();
        *self.loads.get_mut(set) = Load::Fetching { done: 0, total: files.len() };
        self.files.insert(set, vec![None; files.len()]);
        for index in 0..files.len() {
            self.fetch_file(set, index, 1);
        }
    }

    fn fetch_file(&mut self, set: ModelSet, index: usize, attempt: usize) {
        let id = next_id();
        self.waiting.insert(id, For::File { set, index, attempt });
        self.effects.push(Effect::Fetch { id, url: format!("weights/{}", set.files()[index]) });
    }

    /// A download of `set`'s file `index` failed on its `attempt`-th try: it is tried again
    /// after [`FETCH_RETRY_MS`] (the console says so), or, after the last try, the set fails.
    fn fetch_failed(&mut self, set: ModelSet, index: usize, attempt: usize, e: String) {
        if self.loads.get(set).is_settled() {
            return;
        }
        match FETCH_RETRY_MS.get(attempt - 1) {
            Some(wait) => {
                self.console.push(format!("{e}; trying again in {:.0} s", wait / 1000.0));
                self.refetch.push((self.now_ms + wait, set, index, attempt + 1));
            }
            None => self.fail(set, &LoadError::Fetch(e)),
        }
    }

    /// Downloads whose wait is over start again.
    fn start_refetches(&mut self, now_ms: f64) {
        let (due, later) = std::mem::take(&mut self.refetch).into_iter().partition(|r| r.0 <= now_ms);
        self.refetch = later;
        for (_, set, index, attempt) in due {
            if !self.loads.get(set).is_settled() {
                self.fetch_file(set, index, attempt);
            }
        }
    }

    fn post(&mut self, target: Target, epoch: u64, request: Request, what: For) {
        let id = next_id();
        let rest_per_work = if target == Target::Worker { self.rest_per_work } else { 0.0 };
        self.waiting.insert(id, what);
        if target == Target::Worker {
            self.sent.insert(id, self.now_ms);
        }
        self.effects.push(Effect::Post { target, envelope: Envelope { id, epoch, rest_per_work, request } });
    }

    fn fail(&mut self, set: ModelSet, e: &LoadError) {
        let why = reason(set, e);
        *self.loads.get_mut(set) = Load::Failed(why.clone());
        self.files.remove(&set);
        match set {
            ModelSet::World => {
                self.app.set_learned(LearnedStatus::Failed(why.clone()));
            }
            ModelSet::Sketch => {
                self.app.set_sketch_models(LearnedStatus::Failed(why.clone()));
            }
            ModelSet::Tem => self.app.set_refinement(None),
        }
        if let Some(m) = notice(set, &why) {
            self.message = Some(m);
        }
    }

    fn ready(&mut self, set: ModelSet, hash: String) {
        let backend = match set {
            ModelSet::Tem => self.tem_backend(),
            ModelSet::World => self.world_backend(),
            ModelSet::Sketch => self.sketch_backend().into(),
        };
        *self.loads.get_mut(set) = Load::Ready { hash: hash.clone(), backend };
        match set {
            ModelSet::World => {
                // The worker's new learned world has no pins.
                self.pins_sent = Some(String::new());
                if let Some(note) = self.app.set_learned(LearnedStatus::Ready { hash }) {
                    self.message = Some(note);
                }
            }
            ModelSet::Sketch => {
                if let Some(note) = self.app.set_sketch_models(LearnedStatus::Ready { hash }) {
                    self.message = Some(note);
                }
            }
            ModelSet::Tem => {}
        }
    }

    /// A file of `set` arrived: once all have, the set goes to its runner(s).
    fn file_arrived(&mut self, set: ModelSet, index: usize, bytes: Vec<u8>) {
        let Some(slots) = self.files.get_mut(&set) else { return };
        slots[index] = Some(bytes);
        let done = slots.iter().filter(|s| s.is_some()).count();
        let total = slots.len();
        if done < total {
            *self.loads.get_mut(set) = Load::Fetching { done, total };
            return;
        }
        let mut files: Vec<Vec<u8>> = self.files.remove(&set).unwrap_or_default().into_iter().flatten().collect();
        *self.loads.get_mut(set) = Load::Loading;
        match set {
            ModelSet::Tem => {
                if self.probe == Probe::Waiting {
                    self.probe_files = Some(files.clone());
                }
                self.post(self.tem_target, 0, Request::LoadTem { files }, For::Load { set, target: self.tem_target })
            }
            ModelSet::World => {
                let (grow, tcm) = (files.pop().unwrap_or_default(), files.pop().unwrap_or_default());
                if self.gpu.is_ok() && (self.world_nets.is_gpu() || self.world_probe == Probe::Waiting) {
                    // The networks on the GPU too: tiles go there once they load (or the probe
                    // times them there); until then the worker makes whole tiles.
                    self.post(Target::Gpu, 0, Request::LoadWorld { tcm: tcm.clone(), grow: grow.clone() }, For::Load { set, target: Target::Gpu });
                }
                self.post(Target::Worker, 0, Request::LoadWorld { tcm, grow }, For::Load { set, target: Target::Worker });
            }
            ModelSet::Sketch => {
                let (vae, generator) = (files.pop().unwrap_or_default(), files.pop().unwrap_or_default());
                if self.tem_target == Target::Gpu || self.sketch_probe == Probe::Waiting {
                    // The generator on the GPU too: strokes are made there when it loads and
                    // the TEM runs there, and its probe times it against the worker.
                    let request = Request::LoadSketch { generator: generator.clone(), vae: vae.clone() };
                    self.post(Target::Gpu, 0, request, For::Load { set, target: Target::Gpu });
                }
                self.post(Target::Worker, 0, Request::LoadSketch { generator, vae }, For::Load { set, target: Target::Worker });
            }
        }
    }

    /// Pins the DEM in `bytes` (a GeoTIFF that states its pixel size, 32 m or finer; the file
    /// is `name`) into the learned world, centred on the tile under the eye: its whole 32 m
    /// tiles are kept exactly and the world is made again around them
    /// ([`crate::world::pins`]). Returns what to tell the user.
    pub fn pin_dem(&mut self, name: &str, bytes: Vec<u8>) -> Result<String, String> {
        self.can_pin(name)?;
        let hf = crate::dem::Heightfield::read_tiff(std::io::Cursor::new(bytes), f64::NAN).map_err(|e| format!("{name}: {e}"))?;
        if hf.spacing_m.is_nan() {
            return Err(format!("{name} does not say its pixel size: pin a GeoTIFF that does"));
        }
        self.pin_heightfield(name, &hf)
    }

    /// Why terrain named `name` cannot be pinned now, if it cannot: pins go into the learned
    /// world, once its models are loaded.
    fn can_pin(&self, name: &str) -> Result<(), String> {
        if self.app.source() != SourceKind::Learned || !matches!(self.loads.world, Load::Ready { .. }) {
            return Err(format!("{name}: your terrain is pinned into the learned world; choose it in Settings and let its models load first"));
        }
        Ok(())
    }

    /// Pins the heightmap PNG waiting for its answers ([`Self::heightmap`]) with the answers
    /// it has now, as [`Self::pin_dem`] pins a GeoTIFF. On an error it keeps waiting, so the
    /// answers can be changed.
    pub fn pin_heightmap(&mut self) -> Result<String, String> {
        let p = self.heightmap.as_ref().ok_or("no heightmap PNG is waiting to be pinned")?;
        let name = p.name.clone();
        self.can_pin(&name)?;
        let hf = p.heightfield()?;
        let said = self.pin_heightfield(&name, &hf)?;
        self.heightmap = None;
        Ok(said)
    }

    /// Pins `hf` (from the file `name`) centred on the tile under the eye.
    fn pin_heightfield(&mut self, name: &str, hf: &crate::dem::Heightfield) -> Result<String, String> {
        // Whole tiles it covers across and down, to centre it on the eye's tile.
        let cols = (hf.width as f64 * hf.spacing_m / crate::grid::TILE_SIZE_M) as i32;
        let rows = (hf.height as f64 * hf.spacing_m / crate::grid::TILE_SIZE_M) as i32;
        let eye = self.app.camera.position_m;
        let at = TileCoord::containing(eye.x, eye.z).offset(-(cols - 1) / 2, -(rows - 1) / 2);
        let mut pins = Pins::new();
        let added = pins.add(hf, at).map_err(|e| format!("{name}: {e}"))?;
        self.pinned = Some((name.to_string(), added.tiles.len()));
        self.app.set_user_pins(pins);
        Ok(format!(
            "Pinned {name}: {} tile{} from tile ({}, {}){}; the world grows around them. A link does not carry them: \"Save world\" makes a file with the link and your terrain.",
            added.tiles.len(),
            if added.tiles.len() == 1 { "" } else { "s" },
            at.i,
            at.j,
            added.detail_said()
        ))
    }

    /// The world as a bundle file ([`crate::share::bundle`]): the link of the view and the
    /// terrain pinned into it, for a world whose pins a link cannot carry. `None` with nothing
    /// pinned (the link alone is the world).
    pub fn save_world(&self) -> Option<Vec<u8>> {
        let pins = self.app.user_pins();
        (!pins.is_empty()).then(|| WorldBundle { link: self.app.asked_state().to_fragment(), pins: pins.clone() }.to_bytes())
    }

    /// Opens a world bundle ([`Self::save_world`]) named `name`: its link's world and view,
    /// with its terrain pinned. Returns what to tell the user; a file that is not a bundle, or
    /// whose link is broken, changes nothing.
    pub fn open_world(&mut self, name: &str, bytes: &[u8]) -> Result<String, String> {
        let bundle = WorldBundle::from_bytes(bytes).map_err(|e| format!("{name}: {e}"))?;
        let share = ShareState::from_fragment(&bundle.link).map_err(|e| format!("{name}: its link is broken ({e})"))?;
        let tiles = bundle.pins.coords().len();
        self.app.apply(share);
        self.app.set_user_pins(bundle.pins);
        self.pinned = (tiles > 0).then(|| (name.to_string(), tiles));
        let wait = if matches!(self.loads.world, Load::Ready { .. }) { "" } else { " once the learned world's models have loaded" };
        Ok(format!("Opened {name}: its world and view, with {tiles} pinned tiles{wait}."))
    }

    /// A file the user dropped on the page (or opened), by what its bytes are: a world bundle
    /// is opened, a GeoTIFF pinned ([`Self::pin_dem`]), a sketch PNG drawn on the canvas and
    /// shown in the sketch world, another PNG waits as a heightmap for its spacing and heights
    /// ([`Self::heightmap`], [`Self::pin_heightmap`]), and a JSON sidecar of this project's
    /// exports gives them. Returns what to tell the user; anything else is refused with why,
    /// and nothing changes.
    pub fn open_file(&mut self, name: &str, bytes: Vec<u8>) -> Result<String, String> {
        let gzip = bytes.starts_with(&[0x1f, 0x8b]);
        if !gzip && bytes.len() as f64 > MAX_PIN_FILE_BYTES {
            return Err(format!("{name} is {:.1} MB; terrain to pin is at most 65 MB (4096² float32 samples)", bytes.len() as f64 / 1024.0 / 1024.0));
        }
        match bytes.get(..4) {
            Some([0x1f, 0x8b, ..]) => self.open_world(name, &bytes),
            Some(b"II*\0" | b"MM\0*") => self.pin_dem(name, bytes),
            Some([0x89, b'P', b'N', b'G']) => {
                let sketch = match crate::sketch::Sketch::read_png(std::io::Cursor::new(&bytes)) {
                    Ok(s) => s,
                    Err(_) => return self.wait_for_heightmap_answers(name, bytes),
                };
                self.app.canvas.load(sketch);
                if self.app.settings().source != SourceKind::Sketch {
                    self.app.apply_settings(ShareState { source: SourceKind::Sketch, ..self.app.settings().clone() });
                }
                Ok(format!("Opened the sketch {name}: its terrain is made in the sketch world."))
            }
            Some([b'{', ..]) if name.ends_with(".json") => {
                let json: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| format!("{name}: {e}"))?;
                if let Some(p) = &mut self.heightmap
                    && p.apply_sidecar(name, &json)
                {
                    return Ok(format!("{name} gave {}'s spacing and heights: check them and press Pin.", p.name));
                }
                self.sidecars.push((name.to_string(), json));
                let old = self.sidecars.len().saturating_sub(4);
                self.sidecars.drain(..old);
                Ok(format!("{name} is kept for the heightmap PNG it describes."))
            }
            _ => Err(format!("{name}: drop a GeoTIFF or a heightmap PNG to pin, a sketch PNG, or a world bundle (.json.gz)")),
        }
    }

    /// A PNG that is not a sketch: a heightmap that waits for its spacing and heights (from a
    /// sidecar that came before it, if one describes it), or why it is none.
    fn wait_for_heightmap_answers(&mut self, name: &str, bytes: Vec<u8>) -> Result<String, String> {
        let mut p = PendingPng::new(name, bytes).map_err(|e| format!("{e}; nor is it a sketch"))?;
        let from = self.sidecars.iter().rev().find(|(n, j)| p.apply_sidecar(n, j)).map(|(n, _)| n.clone());
        let said = match (&from, p.kind) {
            (Some(side), _) => format!("{name}: a heightmap PNG; {side} gave its spacing and heights: check them and press Pin."),
            (None, PngKind::TerrainRgb) => format!("{name}: a terrain-RGB PNG; say its spacing and press Pin."),
            (None, PngKind::Grey { .. }) => format!("{name}: a heightmap PNG; say its spacing and the heights of its lowest and highest values, and press Pin."),
        };
        self.heightmap = Some(p);
        Ok(said)
    }

    /// Drops the heightmap PNG waiting for its answers.
    pub fn cancel_heightmap(&mut self) {
        self.heightmap = None;
    }

    /// The terrain pinned into the learned world and its file's name, for a page that starts
    /// again after a lost device ([`Kept`]).
    pub fn kept_pins(&self) -> Option<(String, Pins)> {
        self.pinned.as_ref().map(|(name, _)| (name.clone(), self.app.user_pins().clone()))
    }

    /// Pins `pins` (kept from `name`) again, as a page started again after a lost device.
    pub fn restore_pins(&mut self, name: String, pins: Pins) {
        self.pinned = Some((name, pins.coords().len()));
        self.app.set_user_pins(pins);
    }

    /// Takes the pinned terrain out of the learned world ([`Self::pin_dem`]) and makes the
    /// world again without it; nothing when none is pinned.
    pub fn unpin(&mut self) {
        if self.pinned.take().is_some() {
            self.app.set_user_pins(Pins::new());
        }
    }

    /// Takes back what came of an effect.
    pub fn deliver(&mut self, d: Delivery) {
        if let Delivery::Answer(Answer { id, .. }) | Delivery::WorkerGone { id, .. } = &d {
            self.sent.remove(id);
        }
        match d {
            Delivery::Fetched { id, bytes } => match (self.waiting.remove(&id), bytes) {
                (Some(For::File { set, index, .. }), Ok(b)) => self.file_arrived(set, index, b),
                (Some(For::File { set, index, attempt }), Err(e)) => self.fetch_failed(set, index, attempt, e),
                _ => {}
            },
            Delivery::Answer(a) => {
                if let Some(what) = self.waiting.remove(&a.id) {
                    self.answered(what, a.reply);
                }
            }
            Delivery::WorkerGone { id, why } => {
                self.worker_gone(&why);
                if let Some(what) = self.waiting.remove(&id) {
                    self.answered(what, Reply::Failed(format!("the CPU worker stopped ({why})")));
                }
            }
        }
    }

    /// The CPU worker is gone: the learned world and the sketch models fall back, a TEM on it
    /// stops, and procedural tiles are made on the main thread again.
    fn worker_gone(&mut self, why: &str) {
        if self.worker.is_err() {
            return;
        }
        self.worker = Err(why.to_string());
        let stopped = LoadError::WorkerStopped(why.to_string());
        if !matches!(self.loads.world, Load::Failed(_)) {
            self.fail(ModelSet::World, &stopped);
        }
        if self.tem_target == Target::Worker && !matches!(self.loads.tem, Load::Failed(_)) {
            self.fail(ModelSet::Tem, &stopped);
        }
        if self.loads.sketch != Load::Idle && !matches!(self.loads.sketch, Load::Failed(_)) {
            self.fail(ModelSet::Sketch, &stopped);
        }
        for ch in std::mem::take(&mut self.chains) {
            self.drop_chain(ch);
        }
        self.app.set_procedural_elsewhere(false);
    }

    fn answered(&mut self, what: For, reply: Reply) {
        let failed = |r: &Reply| match r {
            Reply::Failed(e) => Some(e.clone()),
            _ => None,
        };
        // Why a request failed: its runner's reason, or the reply that came instead.
        let why = |r: &Reply| failed(r).unwrap_or_else(|| format!("unexpected reply {r:?}"));
        match (what, reply) {
            (For::Load { set: ModelSet::World, target: Target::Gpu }, r) => {
                match r {
                    Reply::Loaded { .. } => self.world_gpu = Some(Ok(())),
                    r => {
                        self.world_gpu_failed(format!("they did not load there: {}", why(&r)));
                    }
                }
                self.refresh_world_backend();
            }
            (For::Load { set, target }, Reply::Loaded { hash }) => {
                if set == ModelSet::Sketch && target == Target::Gpu {
                    self.sketch_gpu_loaded = true;
                    self.set_sketch_on_gpu(self.tem_target == Target::Gpu);
                } else {
                    self.ready(set, hash);
                }
            }
            (For::Load { set: ModelSet::Sketch, target: Target::Gpu }, r) => {
                let why = failed(&r).unwrap_or_default();
                self.console.push(format!("the sketch generator could not run on the GPU ({why}); strokes go to the CPU worker"));
                if self.sketch_probe == Probe::Waiting {
                    self.sketch_probe = Probe::Failed(format!("it did not load on the GPU: {why}"));
                }
            }
            (For::Load { set, .. }, _) if matches!(self.loads.get(set), Load::Failed(_)) => {}
            (For::Load { set, target }, r) => {
                let e = why(&r);
                let err = match (set, target) {
                    (ModelSet::Tem, Target::Gpu) if !e.contains(".bpk") => LoadError::Run { backend: self.tem_backend(), why: e },
                    _ => LoadError::Broken(e),
                };
                self.fail(set, &err);
            }
            (For::Pin(_), Reply::Loaded { hash }) => self.console.push(format!("pins {hash} in the CPU worker")),
            (For::Pin(name), r) => self.message = Some(format!("{name} could not be pinned ({})", why(&r))),
            (For::SketchBase(seed), Reply::Heights { heights, ms }) => match self.app.set_sketch_base(seed, heights) {
                Ok(()) => self.console.push(format!("the learned ground for the sketch in {ms:.0} ms")),
                Err(e) => self.message = Some(format!("{e}; the sketch stands on a smooth foot")),
            },
            (For::SketchBase(_), r) => self.message = Some(format!("the learned ground for the sketch could not be made ({}); it stands on a smooth foot", why(&r))),
            (For::Tile(job, net_ms), Reply::Heights { heights, ms }) => {
                self.app.tile_done(&job, heights, ms + net_ms);
            }
            (For::Tile(job, _), Reply::Stale) => self.app.tile_failed(&job),
            (For::Coarse(job), Reply::Heights { heights, .. }) => {
                self.app.coarse_done(&job, heights);
            }
            (For::Coarse(job), _) => self.app.coarse_failed(&job),
            (For::WorldWork(ch), Reply::Work(NetworkWork::None)) => self.finish_chain(ch),
            (For::WorldWork(ch), Reply::Work(work)) if self.world_on_gpu() => {
                let batch = GpuBatch { keys: work.keys(), rest: work, outputs: Vec::new(), ms: 0.0 };
                self.post_gpu_call(ch, batch);
            }
            // The GPU failed meanwhile: the worker makes the rest of the tile itself.
            (For::WorldWork(ch), Reply::Work(_)) => self.finish_chain(ch),
            // The worker stopped while the chain ran: nothing of the GPU's is to blame.
            (For::RunWork(ch, _) | For::AcceptWork(ch), _) if self.worker.is_err() => self.drop_chain(ch),
            (For::RunWork(mut ch, mut batch), Reply::Outputs { outputs, ms }) => {
                ch.net_ms += ms;
                if !outputs.is_empty() {
                    self.world_gpu_item_ms = Some(ms / outputs.len() as f64);
                }
                batch.outputs.extend(outputs);
                batch.ms += ms;
                if batch.rest.is_empty() {
                    let request = Request::AcceptWork { seed: ch.seed, keys: batch.keys, outputs: batch.outputs, ms: batch.ms };
                    self.post(Target::Worker, ch.job.epoch, request, For::AcceptWork(ch));
                } else if ch.job.epoch != self.app.epoch() {
                    // A new world began: the rest of the batch is not worth the GPU's time.
                    self.drop_chain(ch);
                    self.next_chain();
                } else {
                    self.post_gpu_call(ch, batch);
                }
            }
            (For::RunWork(ch, _), r) => {
                self.world_gpu_failed(format!("a batch failed there: {}", why(&r)));
                self.finish_chain(ch);
            }
            (For::AcceptWork(ch), Reply::Accepted) => self.post_world_work(ch),
            (For::WorldWork(ch) | For::AcceptWork(ch), Reply::Stale) => {
                self.drop_chain(ch);
                self.next_chain();
            }
            (For::AcceptWork(ch), r) => {
                // The worker refused the GPU's outputs (not the batch's sizes): the GPU is not
                // to be trusted with the world; the worker makes the tile itself.
                self.world_gpu_failed(format!("the worker refused its outputs: {}", why(&r)));
                self.finish_chain(ch);
            }
            (For::WorldWork(ch), r) => {
                let (coarse, key) = (ch.coarse, ch.job.key);
                self.drop_chain(ch);
                if !coarse {
                    self.learned_tile_failed(key, &why(&r));
                }
                self.next_chain();
            }
            (For::WorldProbeRun(target), Reply::Outputs { ms, .. }) => {
                if target == Target::Gpu {
                    self.world_gpu_item_ms = Some(ms / WORLD_PROBE_TILES as f64);
                }
                self.world_probe.record(target, ms);
                self.world_probe_next();
            }
            // A new world began while the batch waited: the same run again.
            (For::WorldProbeRun(_), Reply::Stale) => self.world_probe_next(),
            (For::WorldProbeRun(target), r) => {
                let why = format!("a batch on {target:?} failed: {}", failed(&r).unwrap_or_else(|| format!("{r:?}")));
                self.console.push(format!("the world networks' probe failed ({why}); they stay on {}", self.world_backend()));
                self.world_probe = Probe::Failed(why);
            }
            (For::ProbeLoad(_), Reply::Loaded { .. }) => {
                self.probe = Probe::timing(TIMED_RUNS);
                self.probe_next();
            }
            (For::ProbeLoad(target), r) => self.probe_failed(format!("the TEM did not load on {target:?}: {}", failed(&r).unwrap_or_else(|| format!("{r:?}")))),
            (For::ProbeRun(target), Reply::Heights { ms, .. }) => {
                self.probe.record(target, ms);
                self.probe_next();
            }
            // A new world began while the quad waited: the same run again.
            (For::ProbeRun(_), Reply::Stale) => self.probe_next(),
            (For::ProbeRun(target), r) => self.probe_failed(format!("a quad on {target:?} failed: {}", failed(&r).unwrap_or_else(|| format!("{r:?}")))),
            (For::SketchProbeRun(target), Reply::Heights { ms, .. }) => {
                self.sketch_probe.record(target, ms);
                self.sketch_probe_next();
            }
            (For::SketchProbeRun(target), r) => {
                let why = format!("a sketch on {target:?} failed: {}", failed(&r).unwrap_or_else(|| format!("{r:?}")));
                self.console.push(format!("the sketch probe failed ({why}); strokes go to the CPU worker"));
                self.sketch_probe = Probe::Failed(why);
                self.set_sketch_on_gpu(false);
            }
            (For::Tile(job, _), r) => {
                self.app.tile_failed(&job);
                self.learned_tile_failed(job.key, &failed(&r).unwrap_or_default());
            }
            (For::Tem { epoch, keys }, Reply::Heights { heights, ms }) => {
                if let Err(e) = self.app.refine_done(epoch, &keys, &heights, ms) {
                    self.message = Some(format!("TEM inference failed: {e}"));
                }
            }
            (For::Tem { epoch, keys }, Reply::Stale) => self.app.refine_failed(epoch, &keys),
            (For::Tem { epoch, keys }, r) => {
                self.app.refine_failed(epoch, &keys);
                // A TEM whose runner is gone has said so already (its load failed).
                if !matches!(self.loads.tem, Load::Failed(_)) {
                    self.message = Some(format!("TEM inference failed: {}", failed(&r).unwrap_or_default()));
                }
            }
            (For::Sketch(job, _), Reply::Heights { heights, ms }) => {
                if let Err(e) = self.app.sketch_done(&job, heights, ms) {
                    self.message = Some(format!("The sketch could not be made into terrain: {e}. Draw on to try again."));
                }
            }
            (For::Sketch(job, Target::Gpu), r) => {
                // The GPU failed: this stroke and the next ones go to the worker.
                self.console.push(format!("the sketch generator failed on the GPU ({}); strokes go to the CPU worker", failed(&r).unwrap_or_default()));
                self.sketch_on_gpu = false;
                self.app.sketch_failed(&job);
            }
            (For::Sketch(job, _), r) => {
                self.app.sketch_failed(&job);
                self.message = Some(format!("The sketch could not be made into terrain: {}", failed(&r).unwrap_or_else(|| format!("an unexpected reply {r:?}"))));
            }
            (For::Variants(job), Reply::Sketches { sketches, heights, .. }) if self.edits.finish(&job) == Outcome::Accepted => match pair_up(&sketches, heights) {
                Ok(v) => self.variants = Some(v),
                Err(e) => self.message = Some(format!("No variants: {e}")),
            },
            (For::Variants(job), r) => {
                self.edits.fail(&job);
                self.message = Some(format!("No variants: {}", failed(&r).unwrap_or_default()));
            }
            (For::Blend(job), Reply::Sketches { sketches, heights, .. }) if self.edits.finish(&job) == Outcome::Accepted => {
                match pair_up(&sketches, heights).map(|mut v| v.pop()) {
                    Ok(Some((s, _))) => {
                        self.blends += 1;
                        self.app.canvas.load(s);
                    }
                    Ok(None) => self.message = Some("No blend: the reply has no sketch".into()),
                    Err(e) => self.message = Some(format!("No blend: {e}")),
                }
            }
            (For::Blend(job), r) => {
                self.edits.fail(&job);
                self.message = Some(format!("No blend: {}", failed(&r).unwrap_or_default()));
            }
            (For::File { .. }, _) => {}
        }
    }

    /// The worker could not make tile `key` (why): a learned world shown fails with it, and the
    /// procedural world stands in.
    fn learned_tile_failed(&mut self, key: TileCoord, e: &str) {
        if self.app.source() == SourceKind::Learned {
            self.fail(ModelSet::World, &LoadError::Failed(format!("making tile {}, {} failed ({e})", key.i, key.j)));
        }
    }

    /// Variants or a blend are being made.
    pub fn sketch_busy(&self) -> bool {
        self.edits.stats().in_flight > 0
    }

    /// Asks for four variants of the canvas's sketch (the VAE, in the CPU worker).
    pub fn ask_variants(&mut self) {
        if !self.loads.sketch.is_ready() || self.worker.is_err() {
            self.message = Some("Variants need the sketch models, which are not ready.".into());
            return;
        }
        // Asked again while they are being made: the ones on their way come.
        let Some(job) = self.edits.start([SketchEdit::Variants]).pop() else { return };
        let sketch = SketchBytes::from(self.app.canvas.sketch());
        let seed = self.app.stats().sketch_revision;
        self.post(Target::Worker, 0, Request::Variants { sketch, n: 4, seed }, For::Variants(job));
    }

    /// Asks for the blend α·a + (1 − α)·b; while another is being made the latest asked wins.
    pub fn ask_blend(&mut self, a: Sketch, b: Sketch, alpha: f32) {
        self.pending_blend = Some((a, b, alpha));
    }

    /// Starts the work this frame asks for: learned or procedural tiles in the CPU worker, a
    /// TEM batch, the sketch models once the sketch world is shown, the newest sketch, a
    /// pending blend. `now_ms` is the page's clock.
    pub fn start_work(&mut self, now_ms: f64) {
        self.now_ms = now_ms;
        self.check_worker(now_ms);
        self.start_refetches(now_ms);
        // The first picture is whole once every wanted tile has something to draw (stale
        // stand-ins of an earlier world count: a sketch's surroundings being made again).
        if self.app.stats().tiles_uncovered == 0 {
            self.complete_epoch = Some(self.app.epoch());
        }
        self.rest_per_work = runtime::worker_rest_per_work(self.software_adapter, self.complete_epoch == Some(self.app.epoch()));
        self.start_tiles();
        self.start_refinement(now_ms);
        self.start_probe();
        self.start_sketch();
    }

    /// Where the start-up probe is: not wanted, waiting, timing, what it measured, or why it
    /// failed.
    pub fn probe(&self) -> &Probe {
        &self.probe
    }

    /// Starts the probe once the TEM runs and the first view is complete (a person is not
    /// waiting on it): the TEM loads on the other backend.
    fn start_probe(&mut self) {
        if self.probe != Probe::Waiting || !self.loads.tem.is_ready() || self.complete_epoch != Some(self.app.epoch()) {
            return;
        }
        let Some(files) = self.probe_files.take() else {
            return self.probe_failed("the TEM's files were not kept".into());
        };
        let other = if self.tem_target == Target::Gpu { Target::Worker } else { Target::Gpu };
        self.probe = Probe::Loading;
        self.post(other, 0, Request::LoadTem { files }, For::ProbeLoad(other));
    }

    /// Posts the probe's next quad, or, once every run is in, takes the faster backend.
    fn probe_next(&mut self) {
        if let Some(target) = self.probe.next() {
            let request = Request::Enhance { level: 0, n: 1, side: PROBE_SIDE as u32, input: probe_input(0) };
            return self.post(target, self.app.epoch(), request, For::ProbeRun(target));
        }
        let Probe::Done(timings) = self.probe else { return };
        self.tem = runtime::choose_measured(self.tem_choice, self.gpu.clone(), self.software_adapter, timings);
        self.tem_target = if self.tem.is_gpu() { Target::Gpu } else { Target::Worker };
        let backend = self.tem_backend();
        if let Load::Ready { backend: b, .. } = &mut self.loads.tem {
            b.clone_from(&backend);
        }
        self.console.push(format!("TEM probe: {}; the TEM runs on {backend}", timings.label("quad")));
    }

    /// What the sketch generator's probe found, or is doing.
    pub fn sketch_probe(&self) -> &Probe {
        &self.sketch_probe
    }

    /// Strokes go to the GPU (`true`) or the CPU worker; the loaded set's backend says so.
    fn set_sketch_on_gpu(&mut self, on_gpu: bool) {
        self.sketch_on_gpu = on_gpu;
        let backend = self.sketch_backend();
        if let Load::Ready { backend: b, .. } = &mut self.loads.sketch {
            *b = backend.into();
        }
    }

    /// Starts the sketch generator's probe once it has loaded on the GPU and in the worker and
    /// no stroke is being made.
    fn start_sketch_probe(&mut self) {
        if self.sketch_probe != Probe::Waiting || !self.sketch_gpu_loaded || !self.loads.sketch.is_ready() {
            return;
        }
        // A stroke in flight would slow one of the runs: wait for it.
        if !self.waiting.values().any(|w| matches!(w, For::Sketch(..))) {
            self.sketch_probe = Probe::timing(SKETCH_TIMED_RUNS);
            self.sketch_probe_next();
        }
    }

    /// Posts the sketch probe's next run (the canvas's sketch), or, once every run is in,
    /// sends strokes to the faster backend.
    fn sketch_probe_next(&mut self) {
        if let Some(target) = self.sketch_probe.next() {
            let sketch = self.app.canvas.sketch().into();
            let extent_m = self.app.settings().extent_m;
            return self.post(target, 0, Request::Sketch { sketch, extent_m }, For::SketchProbeRun(target));
        }
        let Probe::Done(timings) = self.sketch_probe else { return };
        let gpu = runtime::choose_measured(self.tem_choice, self.gpu.clone(), self.software_adapter, timings).is_gpu();
        self.set_sketch_on_gpu(gpu);
        self.console.push(format!("sketch probe: {}; strokes go to the {}", timings.label("sketch"), self.sketch_backend()));
    }

    fn probe_failed(&mut self, why: String) {
        self.console.push(format!("the TEM probe failed ({why}); the TEM stays on {}", self.tem_backend()));
        self.probe = Probe::Failed(why);
        self.probe_files = None;
    }

    /// A CPU worker that has not answered a request within [`WORKER_TIMEOUT_MS`] is taken for
    /// stalled: everything it holds fails and its work falls back, as if it had died.
    fn check_worker(&mut self, now_ms: f64) {
        let Some(oldest) = self.sent.values().copied().reduce(f64::min) else { return };
        if now_ms - oldest < WORKER_TIMEOUT_MS || self.worker.is_err() {
            return;
        }
        let why = format!("it did not answer a request in {:.0} s", WORKER_TIMEOUT_MS / 1000.0);
        self.worker_gone(&why);
        for id in std::mem::take(&mut self.sent).into_keys() {
            if let Some(what) = self.waiting.remove(&id) {
                self.answered(what, Reply::Failed(format!("the CPU worker stopped ({why})")));
            }
        }
    }

    fn start_tiles(&mut self) {
        if self.worker.is_err() {
            return;
        }
        self.app.set_procedural_elsewhere(true);
        // The worker's learned world gets the pins of the world shown before its tile jobs.
        // A small sketch is set into the learned world's own tile: asked for once per seed.
        if let Some(seed) = self.app.wants_sketch_base().filter(|&s| self.base_asked != Some(s)) {
            self.post(Target::Worker, 0, Request::UnpinnedTile { seed, tile: TileCoord::new(0, 0) }, For::SketchBase(seed));
            self.base_asked = Some(seed);
        }
        let pins = self.app.worker_pins();
        if self.pins_sent.as_ref().is_some_and(|sent| *sent != pins.0) {
            let name = match (&self.pinned, self.app.settings().source) {
                (_, SourceKind::Sketch) => "the sketch".to_string(),
                (Some((name, _)), _) => name.clone(),
                (None, _) => "no terrain".to_string(),
            };
            self.post(Target::Worker, 0, Request::pin(&pins.1), For::Pin(name));
            self.pins_sent = Some(pins.0.clone());
        }
        let seed = self.app.settings().seed;
        let noise = (self.app.source() == SourceKind::Procedural).then(|| self.app.settings().noise);
        // Learned tiles whose networks run on the GPU go through chains of batches.
        let chained = noise.is_none() && self.world_on_gpu();
        // Coarse first: the stand-ins of the learned tiles near the eye go out before the tiles.
        for job in self.app.coarse_jobs() {
            match chained {
                true => self.chains.push_back(Chain { job, coarse: true, seed, net_ms: 0.0 }),
                false => self.post(Target::Worker, job.epoch, Request::Coarse { seed, tile: job.key }, For::Coarse(job)),
            }
        }
        for job in self.app.tile_jobs() {
            match chained {
                true => self.chains.push_back(Chain { job, coarse: false, seed, net_ms: 0.0 }),
                false => self.post(Target::Worker, job.epoch, Request::Tile { seed, tile: job.key, noise }, For::Tile(job, 0.0)),
            }
        }
        self.next_chain();
        self.start_world_probe();
    }

    /// Whether learned tiles have their network work run on the GPU now: the networks run
    /// there ([`Self::world_backend`]) and have loaded.
    pub fn world_on_gpu(&self) -> bool {
        self.world_nets.is_gpu() && matches!(self.world_gpu, Some(Ok(())))
    }

    /// Where the learned world's networks run, for the overlay: "WebGPU", or "CPU worker" and
    /// why.
    pub fn world_backend(&self) -> String {
        let why = match (&self.world_nets, &self.world_gpu) {
            (Backend::Gpu, Some(Ok(()))) => return "WebGPU".into(),
            (_, Some(Err(e))) => format!("WebGPU failed: {e}"),
            (Backend::Gpu, None) => "until they load on WebGPU".into(),
            (Backend::Cpu(CpuReason::SoftwareAdapter), _) => "software WebGPU adapter".into(),
            (Backend::Cpu(CpuReason::Asked), _) => "asked for by ?world=cpu".into(),
            (Backend::Cpu(CpuReason::NoGpuCompute(_)), _) => "no WebGPU compute".into(),
            (Backend::Cpu(CpuReason::Faster(t)), _) => format!("faster: {}", t.label(&world_probe_unit())),
        };
        format!("CPU worker ({why})")
    }

    /// Milliseconds of network work the GPU ran per learned 32 m tile made through it (the
    /// batches it shares with its neighbours counted once), if any was.
    pub fn world_gpu_ms_per_tile(&self) -> Option<f64> {
        let (ms, tiles) = self.world_gpu_ms;
        (tiles > 0).then(|| ms / tiles as f64)
    }

    /// What the world networks' start-up probe found, or is doing.
    pub fn world_probe(&self) -> &Probe {
        &self.world_probe
    }

    /// The world's networks cannot run on the GPU (why): the worker makes whole tiles from
    /// now on, the console and the overlay say so.
    fn world_gpu_failed(&mut self, why: String) {
        if matches!(self.world_gpu, Some(Err(_))) {
            return;
        }
        self.console.push(format!("the learned world's networks cannot run on WebGPU ({why}); the CPU worker makes its tiles"));
        self.world_gpu = Some(Err(why.clone()));
        if matches!(self.world_probe, Probe::Waiting | Probe::Loading | Probe::Timing { .. }) {
            self.world_probe = Probe::Failed(why);
        }
        self.refresh_world_backend();
    }

    /// The learned world's load says where its networks run now.
    fn refresh_world_backend(&mut self) {
        let backend = self.world_backend();
        if let Load::Ready { backend: b, .. } = &mut self.loads.world {
            *b = backend;
        }
    }

    /// Starts the next queued chain unless one runs; chains of an older world are dropped.
    fn next_chain(&mut self) {
        if self.waiting.values().any(For::is_chain) {
            return;
        }
        while let Some(ch) = self.chains.pop_front() {
            if ch.job.epoch == self.app.epoch() && self.worker.is_ok() {
                return self.post_world_work(ch);
            }
            self.drop_chain(ch);
        }
    }

    /// Posts the next call of `batch` to the GPU: its next [`PageCore::gpu_call_items`] items.
    fn post_gpu_call(&mut self, ch: Chain, mut batch: GpuBatch) {
        let work = batch.rest.split_front(self.gpu_call_items());
        let halves = self.gpu_call_halves();
        self.post(Target::Gpu, ch.job.epoch, Request::RunWork { work, halves }, For::RunWork(ch, batch));
    }

    /// Whether the GPU runs a ×4 step's batch in two halves with a frame between them
    /// ([`crate::world::learned::NetworksOn::run`]): where one item takes longer than a call may
    /// ([`GPU_CALL_FRAMES`] median frames). On SwiftShader one item is a call, and the ×4
    /// step's window (1.6 times a TCM tile's work) was what the longest frames waited behind.
    pub fn gpu_call_halves(&self) -> bool {
        self.world_gpu_item_ms.is_some_and(|ms| ms > self.gpu_call_ms())
    }

    /// Milliseconds of work a GPU call may hold: [`GPU_CALL_FRAMES`] median frames (of 60 a
    /// second until a frame is measured).
    fn gpu_call_ms(&self) -> f64 {
        let frame_ms = self.app.stats().frame_ms_median;
        GPU_CALL_FRAMES * if frame_ms > 0.0 { frame_ms } else { 1000.0 / 60.0 }
    }

    /// Items of the world's network work in the GPU's next call: as many as take about
    /// [`GPU_CALL_FRAMES`] median frames at the milliseconds an item took in the last call, at
    /// least one; one until a call has been timed.
    pub fn gpu_call_items(&self) -> usize {
        // An item timed at 0 ms gives no bound but the clamp's.
        self.world_gpu_item_ms.map_or(1, |ms| (self.gpu_call_ms() / ms).clamp(1.0, 1e6) as usize)
    }

    fn post_world_work(&mut self, ch: Chain) {
        let request = Request::WorldWork { seed: ch.seed, tile: ch.job.key, coarse: ch.coarse };
        self.post(Target::Worker, ch.job.epoch, request, For::WorldWork(ch));
    }

    /// The chain's network work is done (or left to the worker): the worker makes its tile,
    /// and the next chain starts.
    fn finish_chain(&mut self, ch: Chain) {
        let (epoch, tile, seed) = (ch.job.epoch, ch.job.key, ch.seed);
        if self.worker.is_err() {
            self.drop_chain(ch);
        } else if ch.coarse {
            self.post(Target::Worker, epoch, Request::Coarse { seed, tile }, For::Coarse(ch.job));
        } else {
            if ch.net_ms > 0.0 {
                self.world_gpu_ms = (self.world_gpu_ms.0 + ch.net_ms, self.world_gpu_ms.1 + 1);
            }
            self.post(Target::Worker, epoch, Request::Tile { seed, tile, noise: None }, For::Tile(ch.job, ch.net_ms));
        }
        self.next_chain();
    }

    /// A chain that will not be finished: its tile may be asked for again.
    fn drop_chain(&mut self, ch: Chain) {
        if ch.coarse { self.app.coarse_failed(&ch.job) } else { self.app.tile_failed(&ch.job) }
    }

    /// Starts the world networks' probe once they have loaded on the GPU and in the worker
    /// and the first view is complete: a batch of [`WORLD_PROBE_TILES`] TCM tiles timed on
    /// each, a warm-up and [`TIMED_RUNS`] timed runs, and the faster runs them from then on.
    fn start_world_probe(&mut self) {
        if self.world_probe != Probe::Waiting || self.world_gpu != Some(Ok(())) || !self.loads.world.is_ready() || self.complete_epoch != Some(self.app.epoch()) {
            return;
        }
        self.world_probe = Probe::timing(TIMED_RUNS);
        self.world_probe_next();
    }

    /// Posts the world probe's next batch, or, once every run is in, takes the faster backend.
    fn world_probe_next(&mut self) {
        if let Some(target) = self.world_probe.next() {
            let request = Request::RunWork { work: NetworkWork::probe(WORLD_PROBE_TILES), halves: false };
            return self.post(target, self.app.epoch(), request, For::WorldProbeRun(target));
        }
        let Probe::Done(timings) = self.world_probe else { return };
        self.world_nets = runtime::choose_measured(self.world_choice, self.gpu.clone(), self.software_adapter, timings);
        self.refresh_world_backend();
        self.console.push(format!("world probe: {}; the learned world's networks run on {}", timings.label(&world_probe_unit()), self.world_backend()));
    }

    fn start_refinement(&mut self, now: f64) {
        let want = (self.refine_on && self.loads.tem.is_ready()).then(|| self.tem_backend());
        if self.app.stats().refine_backend != want.clone().unwrap_or_default() {
            self.app.set_refinement(want.clone());
        }
        if want.is_none() || self.waiting.values().any(|w| matches!(w, For::Tem { .. })) {
            return;
        }
        // On the main thread the CPU path blocks the page while it runs (tens of ms a quad in
        // wasm): one quad at a time, at most one a second, and only while the camera is slow
        // (< 60 m/s), so flights stay smooth and detail fills in where the user looks. The GPU
        // and the worker take whole batches.
        let eye = self.app.camera.position_m;
        let speed = self.last_eye.map_or(0.0, |(p, t)| (eye - p).length() / ((now - t) / 1000.0).max(1e-3));
        self.last_eye = Some((eye, now));
        let blocking = self.tem_target == Target::MainThread;
        if blocking && (now - self.last_main_quad_ms < 1000.0 || speed > 60.0) {
            return;
        }
        let jobs = self.app.refine_jobs(if blocking { 1 } else { REFINE_BATCH });
        let Some(first) = jobs.first() else { return };
        if blocking {
            self.last_main_quad_ms = now;
        }
        let (level, epoch, n) = (first.key.level, first.epoch, jobs.len() as u32);
        let keys: Vec<PatchKey> = jobs.iter().map(|j| j.key).collect();
        let input = jobs.into_iter().flat_map(|j| j.input).collect();
        self.post(self.tem_target, epoch, Request::Enhance { level, n, side: INPUT_SIDE as u32, input }, For::Tem { epoch, keys });
    }

    fn start_sketch(&mut self) {
        if self.app.source() != SourceKind::Sketch {
            return;
        }
        if self.loads.sketch == Load::Idle {
            match self.worker.clone() {
                Ok(()) => self.fetch(ModelSet::Sketch),
                Err(_) => {
                    self.loads.sketch = Load::Failed("no CPU worker".into());
                    let _ = self.app.set_sketch_models(LearnedStatus::Failed("no CPU worker".into()));
                    self.message = Some("The sketch generator needs a Web Worker: showing the band interpolation instead.".into());
                }
            }
        }
        if !self.sketch_busy()
            && let Some((a, b, alpha)) = self.pending_blend.take()
            && let Some(job) = self.edits.start([SketchEdit::Blend]).pop()
        {
            self.post(Target::Worker, 0, Request::Blend { a: (&a).into(), b: (&b).into(), alpha }, For::Blend(job));
        }
        self.start_sketch_probe();
        self.start_sketch_jobs();
    }

    /// Sends the canvas's newest sketch to the generator (the GPU, else the CPU worker) if it
    /// has no terrain yet and none is being made. The shell calls it again right after the
    /// sketch panel, so a stroke goes out in the frame that drew it.
    pub fn start_sketch_jobs(&mut self) {
        if self.worker.is_err() && !self.sketch_on_gpu {
            // The band interpolation is made here by the app (no jobs to send).
            let _ = self.app.sketch_jobs();
            return;
        }
        let target = if self.sketch_on_gpu { Target::Gpu } else { Target::Worker };
        for (job, sketch) in self.app.sketch_jobs() {
            let extent_m = self.app.settings().extent_m;
            self.post(target, 0, Request::Sketch { sketch: (&sketch).into(), extent_m }, For::Sketch(job, target));
        }
    }
}

/// Sketches and their terrains (256² heights each, concatenated) as pairs.
fn pair_up(sketches: &[SketchBytes], heights: Vec<f32>) -> Result<Vec<(Sketch, Vec<f32>)>, String> {
    let n = SKETCH_PX * SKETCH_PX;
    if heights.len() != sketches.len() * n {
        return Err("the reply has the wrong number of heights".into());
    }
    sketches.iter().zip(heights.chunks(n)).map(|(s, h)| Ok((s.sketch().map_err(|e| e.to_string())?, h.to_vec()))).collect()
}

#[path = "page_link.rs"]
mod link;

#[cfg(test)]
#[path = "page_tests.rs"]
mod tests;
