//! The page's core driven natively, as the browser shell drives it: effects carried out
//! (files read from `weights/`, requests answered by the same [`Runner`] the Web Worker
//! runs), deliveries handed back.

use super::*;
use crate::jobs::runner::Runner;
use crate::render::camera::ControlInput;
use crate::world::learned::{GROW_FILE, LearnedModels, LearnedSource, TCM_FILE};
use crate::world::{Neighbourhood, TileSource};

fn weights() -> std::path::PathBuf {
    crate::repo_root().join("weights")
}

fn start(worker: Result<(), String>) -> PageStart {
    PageStart { tem: TemChoice::Auto, world: TemChoice::Auto, gpu: Err("no GPU in this test".into()), software_adapter: false, worker, status: String::new() }
}

/// A stand-in for a file's download: `Some(answer)` for the files it changes.
type Swap = dyn Fn(&str) -> Option<Result<Vec<u8>, String>>;

/// A shell: files from `weights/` (or `swap`'s answer for a file name), requests to `runner`.
struct Shell<'a> {
    runner: Runner,
    swap: &'a Swap,
    posted: Vec<(Target, &'static str)>,
    /// The page clock of the next frame (ms) and how far it moves per frame.
    clock_ms: f64,
    frame_ms: f64,
    /// The downloads asked for, by file name, in order.
    fetched: Vec<String>,
    /// A stand-in for the GPU: a runner of its own whose TEM quads and sketches report this
    /// many ms, and its batches of world network work this many ms an item.
    gpu: Option<(Runner, f64)>,
    /// The items of each batch of world network work posted to the GPU, in order.
    gpu_items: Vec<usize>,
}

impl<'a> Shell<'a> {
    /// A shell with a fresh runner, downloads changed by `swap`.
    fn new(swap: &'a Swap) -> Self {
        Shell { runner: Runner::new(1), swap, posted: Vec::new(), clock_ms: 0.0, frame_ms: 16.0, fetched: Vec::new(), gpu: None, gpu_items: Vec::new() }
    }

    /// Carries out the core's effects, and those their deliveries cause, until none is left.
    fn carry_out(&mut self, core: &mut PageCore) {
        loop {
            let effects = core.take_effects();
            if effects.is_empty() {
                return;
            }
            self.carry_out_once(core, effects);
        }
    }

    fn carry_out_once(&mut self, core: &mut PageCore, effects: Vec<Effect>) {
        for e in effects {
            match e {
                Effect::Fetch { id, url } => {
                    let name = url.trim_start_matches("weights/");
                    self.fetched.push(name.to_string());
                    let bytes = (self.swap)(name).unwrap_or_else(|| std::fs::read(weights().join(name)).map_err(|e| format!("{url}: {e}")));
                    core.deliver(Delivery::Fetched { id, bytes });
                }
                Effect::Post { target, envelope } => {
                    self.posted.push((target, envelope.request.kind()));
                    let answer = match (target, &mut self.gpu) {
                        (Target::Gpu, Some((gpu, gpu_ms))) => {
                            if let Request::RunWork { work, .. } = &envelope.request {
                                self.gpu_items.push(work.len());
                            }
                            let mut answer = gpu.handle(envelope);
                            match &mut answer.reply {
                                Reply::Heights { ms, .. } => *ms = *gpu_ms,
                                Reply::Outputs { ms, outputs } => *ms = *gpu_ms * outputs.len() as f64,
                                _ => {}
                            }
                            answer
                        }
                        (Target::Gpu, None) => panic!("no GPU here"),
                        _ => self.runner.handle(envelope),
                    };
                    core.deliver(Delivery::Answer(answer));
                }
            }
        }
    }

    /// `frames` frames of [`Shell::frame_ms`] at the default view, carrying out each frame's
    /// effects.
    fn frames(&mut self, core: &mut PageCore, frames: usize) {
        for _ in 0..frames {
            core.app.frame(&ControlInput::default(), 0.016, [640, 400]);
            core.start_work(self.clock_ms);
            self.clock_ms += self.frame_ms;
            self.carry_out(core);
        }
    }
}

fn no_swap(_: &str) -> Option<Result<Vec<u8>, String>> {
    None
}

/// On a hardware adapter whose GPU passed its self-check the TEM starts on the GPU. Once the
/// first view is complete (not before) the probe loads the TEM into the worker and times a
/// warm-up and three quads on each: with the GPU's quads answered as taking 10 s the worker
/// wins, the TEM moves there (later quads go to the worker, the TEM's backend says why, the
/// console says both times); with 0.001 ms the GPU keeps it. With `?tem=gpu` no probe runs.
#[test]
fn the_start_up_probe_moves_the_tem_to_the_faster_backend_once_the_first_view_is_complete() {
    for (gpu_ms, on_gpu) in [(10_000.0, false), (0.001, true)] {
        let gpu_start = PageStart { gpu: Ok(()), ..start(Ok(())) };
        // The procedural world: its tiles are quick, and the TEM refines it as any other.
        let mut core = PageCore::new(ShareState { source: SourceKind::Procedural, position_m: [2048.0, 900.0, 2048.0], pitch: -0.6, ..ShareState::default() }, gpu_start);
        let mut shell = Shell::new(&no_swap);
        shell.gpu = Some((Runner::new(1), gpu_ms));
        assert_eq!(core.tem_target(), Target::Gpu);
        shell.frames(&mut core, 1);
        assert!(core.loads.tem.is_ready() && core.app.stats().tiles_uncovered > 0, "{:?}", core.app.stats());
        assert_eq!(*core.probe(), Probe::Waiting, "the probe waits for the first view");
        shell.frames(&mut core, 120);
        assert_eq!(core.app.stats().tiles_uncovered, 0);
        let Probe::Done(t) = *core.probe() else { panic!("{:?}", core.probe()) };
        assert_eq!(t.gpu_ms, gpu_ms);
        assert!(t.cpu_ms > 0.0 && t.cpu_ms < 10_000.0, "{t:?}");
        let enhances = |s: &Shell, target| s.posted.iter().filter(|(t, k)| *t == target && *k == "enhance").count();
        assert!(enhances(&shell, Target::Worker) > super::super::probe::TIMED_RUNS, "the worker's probe quads (a warm-up and the timed ones)");
        assert_eq!(core.tem_target() == Target::Gpu, on_gpu, "gpu {gpu_ms} ms, cpu {} ms", t.cpu_ms);
        assert_eq!(core.tem_backend(), if on_gpu { "WebGPU".to_string() } else { format!("CPU (faster: {})", t.label("quad")) });
        assert!(matches!(&core.loads.tem, Load::Ready { backend, .. } if *backend == core.tem_backend()));
        assert!(core.console.iter().any(|l| l.starts_with("TEM probe: WebGPU")), "{:?}", core.console);
        // Later quads go to the winner.
        let before = (enhances(&shell, Target::Gpu), enhances(&shell, Target::Worker));
        core.app.camera.position_m += DVec3::new(1500.0, 0.0, 1500.0);
        shell.frames(&mut core, 60);
        let after = (enhances(&shell, Target::Gpu), enhances(&shell, Target::Worker));
        if on_gpu {
            assert!(after.0 > before.0 && after.1 == before.1, "{before:?} -> {after:?}");
        } else {
            assert!(after.1 > before.1 && after.0 == before.0, "{before:?} -> {after:?}");
        }
    }
    let asked = PageCore::new(ShareState::default(), PageStart { gpu: Ok(()), tem: TemChoice::Gpu, ..start(Ok(())) });
    assert_eq!(*asked.probe(), Probe::Off);
}

/// A core at the default view whose models `shell` loaded, and the effects of its next round
/// of work (started at page time `now_ms`), which the caller holds unanswered.
fn with_work_held(shell: &mut Shell, now_ms: f64) -> (PageCore, Vec<Effect>) {
    let mut core = PageCore::new(ShareState::default(), start(Ok(())));
    shell.frames(&mut core, 1);
    core.app.frame(&ControlInput::default(), 0.016, [640, 400]);
    core.start_work(now_ms);
    let held = core.take_effects();
    (core, held)
}

/// Started with a worker and no GPU, the core fetches both model sets, loads them into the
/// runner, says where each runs ("CPU (no WebGPU compute)" for the TEM), and then makes the
/// learned world's tiles there: bit-identical to the learned source called directly, and
/// learned detail refines (quads made).
#[test]
fn with_a_worker_the_core_loads_both_sets_and_makes_tiles_and_detail_through_effects_alone() {
    let mut core = PageCore::new(ShareState { position_m: [2048.0, 900.0, 2048.0], pitch: -0.6, ..ShareState::default() }, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 1);
    let models = LearnedModels::from_bytes(&std::fs::read(weights().join(TCM_FILE)).unwrap(), &std::fs::read(weights().join(GROW_FILE)).unwrap()).unwrap();
    assert_eq!(core.loads.world, Load::Ready { hash: models.hash.clone(), backend: "CPU worker (no WebGPU compute)".into() });
    assert!(matches!(&core.loads.tem, Load::Ready { backend, .. } if backend == "CPU (no WebGPU compute)"), "{:?}", core.loads.tem);
    assert!(core.status.ends_with("the TEM runs on the CPU"));
    shell.frames(&mut core, 60);
    assert!(core.app.stats().tiles_generated >= 4, "{:?}", core.app.stats());
    assert!(core.app.stats().quads_made >= 1, "no learned detail: {:?}", core.app.stats());
    let c = crate::grid::TileCoord::new(0, 0);
    let want = LearnedSource::new(std::sync::Arc::new(models), 1).generate(core.app.settings().seed, c, &Neighbourhood::default()).heights;
    assert_eq!(core.app.tile_heights(c).unwrap(), &want[..]);
    assert!(shell.posted.iter().all(|(t, _)| *t == Target::Worker));
    assert!(shell.posted.iter().any(|(_, k)| *k == "enhance") && shell.posted.iter().any(|(_, k)| *k == "tile"));
    assert_eq!(core.message, None);
}

/// A TEM file that is not a burnpack fails the TEM with a reason naming the file and
/// "showing the 32 m world" (no message box: the overlay shows it), and a learned-world file
/// that cannot be downloaded fails the learned world with the message that the procedural
/// world stands in, which the app then shows.
#[test]
fn broken_and_missing_weight_files_fail_their_set_with_the_fallback_said() {
    let swap = |name: &str| match name {
        "tem_2_4m.bpk" => Some(Ok(b"this is not a burnpack file".to_vec())),
        n if n == GROW_FILE => Some(Err("weights/grow_32m.bpk: HTTP 404".into())),
        _ => None,
    };
    let mut core = PageCore::new(ShareState::default(), start(Ok(())));
    let mut shell = Shell::new(&swap);
    // A missing file is asked for three times (now, 1 s and 4 s later) before the set fails.
    shell.frame_ms = 500.0;
    shell.frames(&mut core, 10);
    assert_eq!(shell.fetched.iter().filter(|f| *f == GROW_FILE).count(), 3, "{:?}", shell.fetched);
    let Load::Failed(tem) = &core.loads.tem else { panic!("{:?}", core.loads.tem) };
    assert!(tem.contains("tem_2_4m.bpk") && tem.starts_with("TEM weights are broken") && tem.ends_with("showing the 32 m world"), "{tem}");
    assert_eq!(
        core.message.as_deref(),
        Some("The learned world is not available: its weights could not be loaded (weights/grow_32m.bpk: HTTP 404). Showing the procedural world.")
    );
    assert_eq!(core.app.source(), SourceKind::Procedural);
    assert_eq!(core.app.stats().refine_backend, "");
}

/// A download that fails twice and then arrives: the learned world loads (no message, the
/// learned source shown), the console says each retry and its wait (1 s, then 3 s), and the
/// file was asked for no more than 3 times; the second retry comes no sooner than 4 s after
/// the first try.
#[test]
fn a_weight_download_that_fails_twice_is_tried_again_and_the_learned_world_loads() {
    let failures = std::rc::Rc::new(std::cell::Cell::new(0));
    let swap = move |name: &str| {
        (name == TCM_FILE && failures.get() < 2).then(|| {
            failures.set(failures.get() + 1);
            Err(format!("weights/{TCM_FILE}: the connection was reset"))
        })
    };
    let mut core = PageCore::new(ShareState::default(), start(Ok(())));
    let mut shell = Shell::new(&swap);
    shell.frame_ms = 250.0;
    // 0 ms: the first try fails; 1,000 ms: the second; 4,000 ms: the third arrives.
    shell.frames(&mut core, 16);
    assert!(matches!(core.loads.world, Load::Fetching { .. }), "still waiting at 3,750 ms: {:?}", core.loads.world);
    shell.frames(&mut core, 4);
    assert!(core.loads.world.is_ready(), "{:?}", core.loads.world);
    assert_eq!(core.app.source(), SourceKind::Learned);
    assert_eq!(core.message, None);
    assert_eq!(shell.fetched.iter().filter(|f| *f == TCM_FILE).count(), 3, "{:?}", shell.fetched);
    let retries: Vec<&String> = core.console.iter().filter(|c| c.contains("trying again")).collect();
    assert_eq!(retries.len(), 2, "{:?}", core.console);
    assert!(retries[0].ends_with("the connection was reset; trying again in 1 s") && retries[1].ends_with("trying again in 3 s"), "{retries:?}");
}

/// A broken TCM file (bytes that are not weights) fails the learned world with the file named
/// in the message, and the procedural world stands in.
#[test]
fn a_broken_tcm_file_is_named_and_the_procedural_world_stands_in() {
    let swap = |name: &str| (name == TCM_FILE).then(|| Ok(b"not a burnpack file".to_vec()));
    let mut core = PageCore::new(ShareState::default(), start(Ok(())));
    let mut shell = Shell::new(&swap);
    shell.frames(&mut core, 2);
    let message = core.message.clone().unwrap_or_default();
    assert!(message.starts_with("The learned world is not available") && message.contains(TCM_FILE) && message.ends_with("Showing the procedural world."), "{message}");
    assert_eq!(core.app.source(), SourceKind::Procedural);
}

/// A worker that dies with requests in flight: those requests fail, the learned world falls
/// back to the procedural one (made on the main thread again) with a message, and the TEM on
/// the worker stops; nothing stays in flight.
#[test]
fn a_dead_worker_fails_what_it_held_and_its_work_falls_back() {
    let mut shell = Shell::new(&no_swap);
    let (mut core, effects) = with_work_held(&mut shell, 100.0);
    let held: Vec<u32> = effects.into_iter().filter_map(|e| if let Effect::Post { envelope, .. } = e { Some(envelope.id) } else { None }).collect();
    assert!(!held.is_empty());
    for id in held {
        core.deliver(Delivery::WorkerGone { id, why: "out of memory".into() });
    }
    assert_eq!(core.in_flight(), 0);
    assert_eq!(core.app.source(), SourceKind::Procedural);
    assert!(core.message.as_deref().unwrap_or("").contains("the CPU worker stopped (out of memory)"), "{:?}", core.message);
    assert!(matches!(&core.loads.tem, Load::Failed(w) if w.starts_with("The CPU worker stopped")));
    let before = shell.posted.len();
    shell.frames(&mut core, 3);
    assert_eq!(shell.posted.len(), before, "nothing more goes to a dead worker: {:?}", &shell.posted[before..]);
    assert!(core.app.stats().tiles_generated > 0, "procedural tiles are made here");
}

/// Without a worker, the learned world says it needs one and the procedural world stands in;
/// the TEM runs on the main thread (one quad at a time).
#[test]
fn without_a_worker_the_world_is_procedural_and_the_tem_runs_on_the_main_thread() {
    let mut core = PageCore::new(ShareState { position_m: [2048.0, 900.0, 2048.0], pitch: -0.6, ..ShareState::default() }, start(Err("blocked".into())));
    assert_eq!(core.message.as_deref(), Some("The learned world is not available: it needs a Web Worker (blocked). Showing the procedural world."));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 40);
    assert_eq!(core.tem_backend(), "CPU (no WebGPU compute) on the main thread");
    assert!(shell.posted.iter().all(|(t, _)| *t == Target::MainThread));
    let batches: Vec<_> = shell.posted.iter().filter(|(_, k)| *k == "enhance").collect();
    assert!(!batches.is_empty() && batches.len() <= 1, "rationed to one quad a second: {}", batches.len());
}

/// The sketch world: its models load when it is first shown, the canvas's sketch becomes
/// terrain in the worker, variants (asked for twice while in flight: posted once) come back as
/// four sketches with terrains, and a blend is drawn on the canvas.
#[test]
fn the_sketch_world_loads_its_models_and_makes_terrain_variants_and_blends() {
    let mut core = PageCore::new(ShareState { source: SourceKind::Sketch, ..ShareState::default() }, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 3);
    assert!(core.loads.sketch.is_ready(), "{:?}", core.loads.sketch);
    assert_eq!(core.app.stats().sketch_shown, core.app.canvas.revision() + 1);
    core.ask_variants();
    core.ask_variants();
    assert!(core.sketch_busy());
    assert_eq!(core.in_flight(), 1, "variants asked for twice while in flight are posted once");
    shell.carry_out(&mut core);
    assert!(!core.sketch_busy());
    let v = core.variants.take().expect("variants");
    assert_eq!(v.len(), 4);
    assert!(v.iter().all(|(_, h)| h.len() == SKETCH_PX * SKETCH_PX));
    let rev = core.app.canvas.revision();
    core.ask_blend(v[0].0.clone(), v[1].0.clone(), 0.5);
    shell.frames(&mut core, 1);
    assert_eq!(core.blends, 1);
    assert!(core.app.canvas.revision() > rev);
}

/// The sketch generator's own probe: with a GPU (hardware adapter, self-check passed) the
/// sketch models load on both the GPU and the worker when the sketch world is shown; the
/// canvas's sketch is then made on each (a warm-up and two timed runs), and the next stroke
/// goes to the faster: the worker when the GPU's sketches are answered as taking 10 s, the GPU
/// at 0.001 ms; the loaded set's backend and the console say which.
#[test]
fn the_sketch_generators_probe_sends_strokes_to_the_faster_backend() {
    for (gpu_ms, on_gpu) in [(10_000.0, false), (0.001, true)] {
        let gpu_start = PageStart { gpu: Ok(()), ..start(Ok(())) };
        let mut core = PageCore::new(ShareState { source: SourceKind::Sketch, ..ShareState::default() }, gpu_start);
        let mut shell = Shell::new(&no_swap);
        shell.gpu = Some((Runner::new(1), gpu_ms));
        shell.frames(&mut core, 4);
        let Probe::Done(t) = *core.sketch_probe() else { panic!("{:?}", core.sketch_probe()) };
        assert_eq!(t.gpu_ms, gpu_ms);
        let sketches = |s: &Shell, target| s.posted.iter().filter(|(t, k)| *t == target && *k == "sketch").count();
        assert!(sketches(&shell, Target::Worker) > super::super::probe::SKETCH_TIMED_RUNS && sketches(&shell, Target::Gpu) > super::super::probe::SKETCH_TIMED_RUNS);
        assert_eq!(core.sketch_backend(), if on_gpu { "WebGPU" } else { "CPU worker" }, "gpu {gpu_ms} ms, cpu {} ms", t.cpu_ms);
        assert!(matches!(&core.loads.sketch, Load::Ready { backend, .. } if backend == core.sketch_backend()), "{:?}", core.loads.sketch);
        assert!(core.console.iter().any(|l| l.starts_with("sketch probe: WebGPU")), "{:?}", core.console);
        let before = (sketches(&shell, Target::Gpu), sketches(&shell, Target::Worker));
        core.app.canvas.load(Sketch::filled(2));
        shell.frames(&mut core, 2);
        let after = (sketches(&shell, Target::Gpu), sketches(&shell, Target::Worker));
        assert_eq!((after.0 - before.0, after.1 - before.1), if on_gpu { (1, 0) } else { (0, 1) }, "the next stroke");
    }
}

/// A generator that answers NaN heights: the page says so in its message, and the same
/// sketch is not asked for again frame after frame (one request over ten frames); the next
/// stroke is.
/// A half-km sketch whose ground (the learned world's own tile (0, 0)) the worker cannot make:
/// the page says so, asks once (not every frame), and the sketch stays pinned on its smooth
/// foot (no soft edge).
#[test]
fn a_small_sketchs_ground_that_fails_is_said_asked_for_once_and_the_sketch_stands_on_its_foot() {
    let share = ShareState { source: SourceKind::Sketch, extent_m: 512.0, relief_m: 375.0, ..ShareState::default() };
    let mut core = PageCore::new(share, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    let mut asked = 0;
    for f in 0..400 {
        core.app.frame(&ControlInput::default(), 0.016, [640, 400]);
        core.start_work(f as f64 * 16.0);
        loop {
            let effects = core.take_effects();
            if effects.is_empty() {
                break;
            }
            for e in effects {
                match e {
                    Effect::Post { envelope, .. } if envelope.request.kind() == "unpinned-tile" => {
                        asked += 1;
                        core.deliver(Delivery::Answer(Answer { id: envelope.id, reply: Reply::Failed("out of memory".into()) }));
                    }
                    e => shell.carry_out_once(&mut core, vec![e]),
                }
            }
        }
        if asked > 0 && core.app.stats().tiles_pending == 0 && f > 100 {
            break;
        }
    }
    assert_eq!(asked, 1, "asked once");
    let m = core.message.clone().unwrap_or_default();
    assert!(m.contains("could not be made (out of memory); it stands on a smooth foot"), "{m}");
    let pins = core.app.worker_pins();
    let tile = pins.1.get(crate::grid::TileCoord::new(0, 0)).expect("the sketch is pinned");
    assert!(tile.soft.is_none() && tile.detail.len() == 4, "on its foot, with its 2 m detail");
}

#[test]
fn a_sketch_terrain_that_is_not_finite_is_said_and_not_asked_for_again_every_frame() {
    let mut core = PageCore::new(ShareState { source: SourceKind::Sketch, ..ShareState::default() }, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 1);
    assert!(core.loads.sketch.is_ready());
    // A stroke; its terrain comes back broken.
    core.app.canvas.set_tool(crate::sketch::canvas::Tool::Ridge);
    core.app.canvas.press(10.0, 10.0);
    core.app.canvas.drag(100.0, 10.0);
    core.app.canvas.release();
    let mut sketches = 0;
    for f in 0..10 {
        core.app.frame(&ControlInput::default(), 0.016, [640, 400]);
        core.start_work(100.0 + f as f64 * 16.0);
        for e in core.take_effects() {
            if let Effect::Post { envelope, .. } = e {
                if envelope.request.kind() != "sketch" {
                    // The learned world around the sketch: its pins and tiles.
                    let answer = shell.runner.handle(envelope);
                    core.deliver(Delivery::Answer(answer));
                    continue;
                }
                sketches += 1;
                let heights = vec![f32::NAN; SKETCH_PX * SKETCH_PX];
                core.deliver(Delivery::Answer(Answer { id: envelope.id, reply: Reply::Heights { heights, ms: 1.0 } }));
            }
        }
    }
    assert_eq!(sketches, 1, "asked once, not every frame");
    let m = core.message.clone().unwrap_or_default();
    assert!(m.starts_with("The sketch could not be made into terrain") && m.contains("65536 of them not finite"), "{m}");
    core.app.canvas.press(10.0, 50.0);
    core.app.canvas.drag(100.0, 50.0);
    core.app.canvas.release();
    core.start_work(400.0);
    let sketch_posts = core.take_effects().iter().filter(|e| matches!(e, Effect::Post { envelope, .. } if envelope.request.kind() == "sketch")).count();
    assert_eq!(sketch_posts, 1, "the next stroke is asked for");
}

/// The sketch panel's extent slider at 0.5 km: the sketch is made again for that extent (the
/// generator is told it, so the terrain differs from the 8 km one), with the relief that fits
/// it (375 m, the user had the default), and set into the learned world's own tile (0, 0)
/// (asked of the worker without pins) with its own 2 m detail: the tile drawn is that
/// detail's area mean bit for bit, within 1 cm of the world's own tile (0, 0) 1 km from the
/// sketch, and the tile beside it is the world's own bit for bit; the camera frames it from
/// 0.4 km (325 m above the macro level, then, once the ground comes, above the ground's
/// level around it, as "Frame the sketch" does) and the link carries the extent and relief.
#[test]
fn the_extent_slider_makes_the_sketch_again_half_a_km_across_with_its_own_2_m_detail() {
    use crate::world::sketched::SketchSource;
    let share = ShareState { source: SourceKind::Sketch, position_m: [0.0, 2500.0, 3000.0], pitch: -0.6, radius_tiles: 1.5, ..ShareState::default() };
    let mut core = PageCore::new(share, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    let settle = |core: &mut PageCore, shell: &mut Shell, extent_m: f64| {
        for _ in 0..800 {
            shell.frames(core, 1);
            let s = core.app.stats();
            let based = core.app.wants_sketch_base().is_none();
            if based && core.app.sketch_terrain_extent_m() == Some(extent_m) && s.sketch_shown == core.app.canvas.revision() + 1 && s.tiles_pending == 0 && s.tiles_stale == 0 {
                return;
            }
        }
        panic!("the sketch world did not settle at {extent_m} m: {:?}", core.app.stats());
    };
    settle(&mut core, &mut shell, 8192.0);
    let wide = core.app.sketch_terrain().unwrap().to_vec();
    let s = core.set_extent(512.0);
    assert_eq!((s.extent_m, s.relief_m), (512.0, 375.0));
    let link = s.to_fragment();
    assert!(link.contains("relief=375&extent=512"), "{link}");
    let c = crate::grid::TileCoord::new(0, 0);
    let eye = core.app.camera.position_m;
    let from_centre = ((eye.x - 2032.0).powi(2) + (eye.z - 2032.0).powi(2)).sqrt();
    assert!((300.0..500.0).contains(&from_centre), "the camera is {from_centre:.0} m from the sketch's centre: {eye:?}");
    let level = crate::world::ranges::macro_level(core.app.settings().seed, c) as f64;
    // A quarter of the relief above that level, and 0.45 extents more (325 m).
    assert!((eye.y - level - 325.0).abs() < 1.0, "the camera is at {:.0} m, the sketch's outer samples at {level:.0} m", eye.y);
    settle(&mut core, &mut shell, 512.0);
    let small = core.app.sketch_terrain().unwrap().to_vec();
    // The generator was told 0.5 km: its terrain for that extent (the shipped weights were
    // trained before the extent channel, so theirs is the 8 km one too).
    let bytes = std::fs::read(weights().join(crate::models::sketch::WEIGHT_FILE)).unwrap();
    let generator = crate::models::sketch::SketchGenCpu::from_burnpack(&bytes).unwrap();
    let want = generator.generate(core.app.canvas.sketch(), 512.0, &mut Default::default(), 1);
    let off = want.iter().zip(&small).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    assert!(off < 0.01, "the terrain shown is {off} of 255 from the generator's at 0.5 km");
    let moved = wide.iter().zip(&small).filter(|(a, b)| (*a - *b).abs() > 1.0).count();
    assert!(!generator.knows_extent() || moved > 1000, "the terrain made for 0.5 km is the 8 km one: {moved} samples differ by over 1 of 255");
    let pins = core.app.worker_pins();
    assert_eq!(pins.1.coords(), vec![c]);
    let seed = core.app.settings().seed;
    let models = std::sync::Arc::new(LearnedModels::load_dir(&weights()).unwrap());
    let free = LearnedSource::new(models, 1);
    let own = free.generate(seed, c, &Neighbourhood::default()).heights;
    let want = SketchSource::with_extent(std::sync::Arc::new(small), 375.0, 512.0, seed).with_base(std::sync::Arc::new(own.clone())).pins();
    let (got, want) = (pins.1.get(c).unwrap(), want.get(c).unwrap());
    assert_eq!(got.detail.len(), 4, "16, 8, 4 and 2 m");
    assert!(got.soft.is_some(), "the sketch is set into the world's own tile");
    assert!(got.detail(3).unwrap().iter().zip(want.detail(3).unwrap()).all(|(a, b)| a.to_bits() == b.to_bits()));
    let tile = core.app.tile_heights(c).unwrap();
    assert!(tile.iter().zip(want.fine.iter()).all(|(a, b)| a.to_bits() == b.to_bits()), "tile (0, 0) is the pin's");
    // 32 m samples 0–31 lie over 1 km from the sketch (1,776–2,288 m).
    let far = (0..32 * 128).map(|k| (tile[k] - own[k]).abs()).fold(0f32, f32::max);
    assert!(far < 0.01, "1 km from the sketch tile (0, 0) is {far} m from the world's own");
    let beside = crate::grid::TileCoord::new(1, 0);
    let world = free.generate(seed, beside, &Neighbourhood::default()).heights;
    assert_eq!(core.app.tile_heights(beside).expect("the tile beside the sketch"), &world[..]);
    // The camera, left where the slider framed it, was framed again from above the ground's
    // own level around the sketch when that ground came; "Frame the sketch" does the same.
    let level = SketchSource::with_extent(std::sync::Arc::new(core.app.sketch_terrain().unwrap().to_vec()), 375.0, 512.0, seed).with_base(std::sync::Arc::new(own)).base_m() as f64;
    let eye = core.app.camera.position_m;
    assert!((eye.y - level - 325.0).abs() < 1.0, "framed at {:.0} m, the ground around the sketch at {level:.0} m", eye.y);
    core.app.camera.position_m.y += 100.0;
    core.app.frame_sketch();
    assert_eq!(core.app.camera.position_m, eye);
}

/// The sketch world with the learned world's models ready is the sketch pinned into the
/// learned world: the worker gets the sketch's pins before any tile of that world; the
/// sketch's four tiles are its terrain × relief / 255 bit for bit and the tile beside them is
/// the learned source's with the sketch pinned. After a stroke, the frame that shows its
/// terrain draws the sketch at once over the old surroundings (stale stand-ins, none of the
/// previous world's picture), no tile is asked for while the sketch has just changed
/// ([`SKETCH_SETTLE_S`](crate::app::SKETCH_SETTLE_S)), and then the surroundings are made
/// again for the new pins.
#[test]
fn the_sketch_world_is_pinned_into_the_learned_world_which_grows_around_it_again_after_a_stroke() {
    use crate::world::sketched::{SKETCH_TILES, SketchSource};
    let share = ShareState { source: SourceKind::Sketch, position_m: [0.0, 2500.0, 3000.0], pitch: -0.6, radius_tiles: 1.5, ..ShareState::default() };
    let mut core = PageCore::new(share, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    let settle = |core: &mut PageCore, shell: &mut Shell| {
        for _ in 0..800 {
            shell.frames(core, 1);
            let s = core.app.stats();
            if s.sketch_shown == core.app.canvas.revision() + 1 && s.tiles_pending == 0 && s.tiles_stale == 0 {
                return;
            }
        }
        panic!("the sketch world did not settle: {:?}", core.app.stats());
    };
    settle(&mut core, &mut shell);
    assert!(core.app.source_name().starts_with("sketch in the learned world"), "{}", core.app.source_name());
    let first_pin = shell.posted.iter().position(|(_, k)| *k == "pin").expect("the sketch's pins sent");
    assert!(shell.posted[..first_pin].iter().all(|(_, k)| *k != "tile"), "a tile was asked for before the pins");
    let models = std::sync::Arc::new(LearnedModels::load_dir(&weights()).unwrap());
    let seed = core.app.settings().seed;
    let check = |core: &PageCore| {
        let sketch = SketchSource::new(std::sync::Arc::new(core.app.sketch_terrain().unwrap().to_vec()), core.app.settings().relief_m);
        for c in SKETCH_TILES {
            let got = core.app.tile_heights(c).expect("a sketch tile");
            assert!(got.iter().zip(sketch.tile(c).heights.iter()).all(|(a, b)| a.to_bits() == b.to_bits()), "sketch tile {c:?}");
        }
        let beside = crate::grid::TileCoord::new(1, 0);
        let want = LearnedSource::new(models.clone(), 1).with_pins(sketch.pins()).generate(seed, beside, &Neighbourhood::default()).heights;
        assert_eq!(core.app.tile_heights(beside).expect("the tile beside the sketch"), &want[..]);
    };
    check(&core);
    // A stroke across the sketch.
    let before = core.app.tile_heights(crate::grid::TileCoord::new(0, 0)).unwrap().to_vec();
    core.app.canvas.set_tool(crate::sketch::canvas::Tool::Ridge);
    core.app.canvas.press(130.0, 20.0);
    core.app.canvas.drag(250.0, 240.0);
    core.app.canvas.release();
    let want = core.app.canvas.revision() + 1;
    for _ in 0..50 {
        shell.frames(&mut core, 1);
        if core.app.stats().sketch_shown == want {
            break;
        }
    }
    assert_eq!(core.app.stats().sketch_shown, want, "the stroke's terrain");
    core.app.frame(&ControlInput::default(), 0.016, [640, 400]);
    let s = core.app.stats().clone();
    assert_ne!(core.app.tile_heights(crate::grid::TileCoord::new(0, 0)).unwrap(), &before[..], "the stroke changed the sketch's tile");
    let drawable = core.app.drawable_tiles();
    assert!(SKETCH_TILES.iter().all(|c| drawable.contains(c)), "the sketch is drawable at once: {drawable:?}");
    assert!(s.tiles_stale > 0 && s.tiles_pending > 0 && s.nodes_drawn > 0 && !s.previous_world_shown, "{s:?}");
    assert!(core.app.tile_jobs().is_empty() && core.app.coarse_jobs().is_empty(), "the surroundings wait while the user draws");
    eprintln!("after the stroke: {} stale tiles stand in, {} pending", s.tiles_stale, s.tiles_pending);
    settle(&mut core, &mut shell);
    check(&core);
}

/// A worker that never answers: once a request has waited [`WORKER_TIMEOUT_MS`], the page
/// takes the worker for stalled — the learned world falls back to the procedural one with a
/// message that says so, nothing stays in flight, and nothing more is sent to it. A minute
/// less one millisecond changes nothing.
#[test]
fn a_worker_that_does_not_answer_for_a_minute_is_taken_for_stalled_and_its_work_falls_back() {
    let mut shell = Shell::new(&no_swap);
    let (mut core, effects) = with_work_held(&mut shell, 1000.0);
    let held = effects.len();
    assert!(held > 0 && core.in_flight() == held, "{held} requests, {} in flight", core.in_flight());
    core.start_work(1000.0 + WORKER_TIMEOUT_MS - 1.0);
    assert!(core.worker().is_ok() && core.in_flight() == held);
    core.start_work(1000.0 + WORKER_TIMEOUT_MS);
    assert_eq!(core.in_flight(), 0);
    assert_eq!(core.app.source(), SourceKind::Procedural);
    let m = core.message.clone().unwrap_or_default();
    assert!(m.contains("the CPU worker stopped (it did not answer a request in 60 s)"), "{m}");
    core.app.frame(&ControlInput::default(), 0.016, [640, 400]);
    core.start_work(70_000.0);
    assert!(core.take_effects().iter().all(|e| !matches!(e, Effect::Post { target: Target::Worker, .. })));
}

/// A core started again on the same worker (after a lost device) after the first core went
/// through many worlds: its tiles are made, not dropped as stale (its epochs follow the first
/// core's).
#[test]
fn a_core_started_again_on_the_same_worker_has_its_tiles_made() {
    let mut shell = Shell::new(&no_swap);
    let share = ShareState { source: SourceKind::Procedural, ..ShareState::default() };
    let mut first = PageCore::new(share.clone(), start(Ok(())));
    for seed in 2..12 {
        first.app.apply(ShareState { seed, ..share.clone() });
        shell.frames(&mut first, 1);
    }
    assert!(first.app.epoch() >= 10);
    let mut second = PageCore::new(share, start(Ok(())));
    assert!(second.app.epoch() > first.app.epoch());
    shell.frames(&mut second, 3);
    let jobs = second.app.stats().tile_jobs;
    assert!(jobs.done > 0 && jobs.stale == 0, "{jobs:?}");
}

/// A link followed in the same tab (the fragment edited) with other weights than the page's
/// ready models gets the note that the world may differ; the address bar keeps the learned
/// world while it is shown.
#[test]
fn a_link_followed_in_the_same_tab_with_other_weights_gets_the_note() {
    let mut core = PageCore::new(ShareState::default(), start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 1);
    assert!(core.loads.world.is_ready() && core.message.is_none());
    let link = ShareState { seed: 9, weights: Some("00d1".into()), ..ShareState::default() }.to_fragment();
    assert!(core.follow_link(&format!("#{link}")).is_some());
    let m = core.message.clone().unwrap_or_default();
    assert!(m.contains("learned-world weights 00d1"), "{m}");
    let written = core.link_to_write(5000.0, true).unwrap_or_default();
    assert!(written.contains("seed=9") && written.contains("src=tcm"), "{written}");
}

/// Coarse first: the learned world's 128 m stand-ins are asked for before its tiles, drawn
/// while no tile around the eye can be drawn yet (each is the tile's root node, bit for bit
/// the runner's 128 m network tile on its vertices), and once every wanted tile is made only
/// tiles that still cannot be drawn (a neighbour outside the wanted ring) keep one: fewer
/// than at first.
#[test]
fn the_learned_world_draws_coarse_stand_ins_before_its_tiles_and_only_undrawable_ones_after() {
    let share = ShareState { radius_tiles: 1.0, position_m: [2048.0, 3000.0, 2048.0], pitch: -1.2, ..ShareState::default() };
    let mut core = PageCore::new(share, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 3);
    let first = |kind: &str| shell.posted.iter().position(|(_, k)| *k == kind).unwrap_or(usize::MAX);
    assert!(first("coarse") < first("tile"), "{:?}", shell.posted);
    let s = core.app.stats().clone();
    assert!(s.coarse_drawn > 0 && s.coarse_drawn == s.nodes_drawn, "{s:?}");
    let eye = crate::grid::TileCoord::new(0, 0);
    let models = std::sync::Arc::new(LearnedModels::load_dir(&weights()).unwrap());
    let want = LearnedSource::new(models, 1).eroded_tile(core.app.settings().seed, eye);
    let node = crate::world::quadtree::NodeData::from_coarse(eye, &core.app.world, 1).expect("the eye's stand-in");
    let n = crate::world::stream::COARSE_SAMPLES;
    assert!((0..n * n).all(|p| node.at((p % n) as i32, (p / n) as i32) == want[p]));
    let early = s.coarse_drawn;
    shell.frames(&mut core, 200);
    let s = core.app.stats().clone();
    assert_eq!(s.tiles_pending, 0, "{s:?}");
    assert!(s.coarse_drawn < early && s.nodes_drawn > s.coarse_drawn, "{s:?}");
    let (world, [x, _, z]) = (&core.app.world, s.eye_m);
    let drawable = world.drawable(x, z);
    let left = world.coarse_stand_ins(x, z, &drawable);
    assert!(left.iter().all(|(c, _)| !c.window3x3().iter().all(|n| world.contains(*n))), "{:?}", left.iter().map(|l| l.0).collect::<Vec<_>>());
}

/// Terrain to the horizon: once the learned view's tiles are made, the far field's 128 m
/// tiles are asked for and arrive, all of them out to 60 km (the farthest at least
/// 14 tiles from the eye), and drawn with every 4th vertex in the frustum beyond the detailed
/// tiles; the view reaches 61 km (its far plane) instead of the radius.
#[test]
fn the_learned_world_draws_a_far_field_out_to_60_km_once_its_tiles_are_made() {
    use crate::world::stream::FAR_FIELD_M;
    let share = ShareState { radius_tiles: 1.0, position_m: [2048.0, 3000.0, 2048.0], pitch: -0.1, ..ShareState::default() };
    let mut core = PageCore::new(share, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 400);
    let s = core.app.stats().clone();
    assert_eq!(s.tiles_pending, 0, "{s:?}");
    let (world, [x, _, z]) = (&core.app.world, s.eye_m);
    let ring = world.far_ring(x, z);
    let have = world.far_stand_ins(&ring);
    assert_eq!(have.len(), ring.len(), "every far tile arrived");
    let farthest = have.iter().map(|(c, _)| c.distance_tiles(x, z)).fold(0.0, f64::max);
    assert!((14.0..=FAR_FIELD_M / crate::world::TILE_SIZE_M).contains(&farthest), "{farthest}");
    assert!(have.iter().all(|(c, _)| c.distance_tiles(x, z) > 1.0));
    assert!(s.far_drawn > 20 && s.far_drawn < ring.len(), "culled to the frustum: {s:?}");
    assert!(core.app.camera.far_m >= FAR_FIELD_M as f32);
}

/// A new seed keeps the old picture only until each tile within a tile of the eye has this
/// world's coarse stand-in (those behind the eye, out of view, included): the old picture
/// goes while some of those tiles are still being made.
#[test]
fn a_new_learned_seed_drops_the_old_picture_once_the_near_tiles_stand_in() {
    let share = ShareState { radius_tiles: 2.0, position_m: [2048.0, 3000.0, 2048.0], pitch: -0.1, ..ShareState::default() };
    let mut core = PageCore::new(share, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 300);
    assert_eq!(core.app.stats().tiles_pending, 0);
    core.app.apply(ShareState { seed: 2, ..core.app.share_state() });
    let mut kept = 0;
    for _ in 0..100 {
        shell.frames(&mut core, 1);
        if !core.app.stats().previous_world_shown {
            break;
        }
        kept += 1;
    }
    let (world, eye) = (&core.app.world, core.app.camera.position_m);
    let near: Vec<_> = world.wanted(eye.x, eye.z).into_iter().filter(|c| c.distance_tiles(eye.x, eye.z) <= 1.0).collect();
    let made = near.iter().filter(|c| world.contains(**c)).count();
    eprintln!("old picture kept {kept} frames; {made} of {} near tiles made when it went", near.len());
    assert!(kept > 0 && !core.app.stats().previous_world_shown);
    assert!(near.iter().all(|c| world.contains(*c) || world.coarse(*c).is_some()));
    assert!(made < near.len(), "{made} of {} near tiles made when the old picture went", near.len());
}

/// The widest view a link may ask for (radius 16 tiles, LOD target 0.5 px) with learned
/// detail on, made through the worker: without a budget it selects thousands of nodes (the
/// review's ~22,000 resident meshes, ~960 MB, came from such a link); with the budget of a
/// device that offers 256 MiB buffers (half its mesh slots) the app raises its LOD target
/// until the view fits, and the last 50 of 400 frames draw at most 5 % over it, while the
/// TEM still refines.
#[test]
fn the_widest_link_with_learned_detail_fits_the_node_budget() {
    let widest =
        ShareState { radius_tiles: 16.0, lod_px: 0.5, source: crate::world::SourceKind::Procedural, position_m: [2048.0, 1500.0, 2048.0], pitch: -0.3, ..ShareState::default() };
    let budget = crate::render::node_budget(crate::render::MESH_MEMORY_BUDGET);
    let run = |limit: Option<usize>| {
        let mut core = PageCore::new(widest.clone(), start(Ok(())));
        if let Some(b) = limit {
            core.app.set_node_budget(b);
        }
        let mut shell = Shell::new(&no_swap);
        let mut drawn = Vec::new();
        for _ in 0..400 {
            shell.frames(&mut core, 1);
            drawn.push(core.app.stats().nodes_drawn);
        }
        (drawn, core.app.stats().clone())
    };
    let (free, s) = run(None);
    let (fitted, f) = run(Some(budget));
    let most = |v: &[usize]| v.iter().copied().max().unwrap_or(0);
    eprintln!(
        "budget {budget} nodes ({} MiB of meshes); without it {} nodes drawn at most ({:.0} MiB), {} quads; with it {} at most in the last 50 frames, LOD {:.2} px, {} quads",
        (budget * 2 * crate::render::MESH_BYTES as usize) >> 20,
        most(&free),
        (most(&free) as u64 * crate::render::MESH_BYTES) as f64 / (1u64 << 20) as f64,
        s.quads_made,
        most(&fitted[350..]),
        f.lod_px_effective,
        f.quads_made
    );
    assert!(most(&free) > budget, "the widest view fits without a budget: {}", most(&free));
    assert!(most(&fitted[350..]) <= budget + budget / 20, "{:?}", &fitted[350..]);
    assert!(f.lod_px_effective > 0.5 && f.quads_made > 0, "{f:?}");
}

/// Your terrain in the page: a 32 m GeoTIFF of 2 × 2 tiles is refused (with the reason)
/// before the learned world's models are loaded; once they are, it is pinned centred on the
/// eye's tile ((0, 0): tiles (0, 0)–(1, 1)), the message says so and that links do not carry
/// pins, the worker makes the pinned tile as the pin's heights bit for bit, and the tile beside
/// the pin is the pinned world's (the learned source with the same pins, called directly);
/// unpinned, the tile is the world's without pins again.
#[test]
fn a_pinned_geotiff_becomes_the_tiles_around_the_eye_the_world_grows_around_it_and_unpinning_restores_it() {
    use crate::grid::TileCoord;
    let mut core = PageCore::new(ShareState { position_m: [2048.0, 900.0, 2048.0], pitch: -0.6, radius_tiles: 1.5, ..ShareState::default() }, start(Ok(())));
    let n = 256;
    let dem = crate::dem::Heightfield::new(n, n, 32.0, (0..n * n).map(|p| 1500.0 + (p % n) as f32 * 3.0 + ((p / n) as f32 * 0.2).sin() * 40.0).collect());
    let mut bytes = std::io::Cursor::new(Vec::new());
    dem.write_tiff(&mut bytes).unwrap();
    let bytes = bytes.into_inner();
    let refused = core.pin_dem("mine.tif", bytes.clone()).unwrap_err();
    assert!(refused.contains("learned world"), "{refused}");
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 1);
    let said = core.pin_dem("mine.tif", bytes).unwrap();
    assert!(said.starts_with("Pinned mine.tif: 4 tiles from tile (0, 0)") && said.contains("A link does not carry them"), "{said}");
    let (pinned, beside) = (TileCoord::new(0, 0), TileCoord::new(-1, 0));
    for _ in 0..400 {
        if core.app.tile_heights(pinned).is_some() && core.app.tile_heights(beside).is_some() {
            break;
        }
        shell.frames(&mut core, 1);
    }
    let mut pins = crate::world::pins::Pins::new();
    pins.add(&dem, pinned).unwrap();
    let pin = pins.get(pinned).unwrap().fine.clone();
    let got = core.app.tile_heights(pinned).expect("the pinned tile made");
    assert!(got.iter().zip(pin.iter()).all(|(a, b)| a.to_bits() == b.to_bits()), "the pinned tile is not the pin");
    let models = LearnedModels::load_dir(&weights()).unwrap();
    let want = LearnedSource::new(std::sync::Arc::new(models), 1).with_pins(pins).generate(core.app.settings().seed, beside, &Neighbourhood::default()).heights;
    assert_eq!(core.app.tile_heights(beside).expect("the tile beside made"), &want[..]);
    assert!(shell.posted.iter().any(|(_, k)| *k == "pin"));
    assert_eq!(core.pinned, Some(("mine.tif".to_string(), 4)));
    // Unpinned: the world without it again.
    core.unpin();
    assert_eq!(core.pinned, None);
    for _ in 0..400 {
        if core.app.tile_heights(pinned).is_some() {
            break;
        }
        shell.frames(&mut core, 1);
    }
    let free =
        LearnedSource::new(std::sync::Arc::new(LearnedModels::load_dir(&weights()).unwrap()), 1).generate(core.app.settings().seed, pinned, &Neighbourhood::default()).heights;
    assert_eq!(core.app.tile_heights(pinned).expect("the tile made again"), &free[..]);
}

/// An 8 m GeoTIFF pinned in the page keeps its own detail: the message says so, and once the
/// TEM refines the view low over it, the page's 8 m export there is the pin's own 8 m heights
/// bit for bit (a whole patch at least), not the TEM's; its 16 m export is their 2 × 2 means.
#[test]
fn an_8_m_geotiff_pinned_in_the_page_is_its_own_detail_where_the_view_is_refined() {
    use crate::grid::TileCoord;
    let mut core = PageCore::new(ShareState { position_m: [2048.0, 2000.0, 2048.0], pitch: -0.6, radius_tiles: 1.0, ..ShareState::default() }, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 1);
    let n = 520;
    let dem = crate::dem::Heightfield::new(
        n,
        n,
        8.0,
        (0..n * n).map(|k| 1200.0 + (k % n) as f32 * 0.3 + ((k % n) as f32 * 0.9).sin() * 6.0 + ((k / n) as f32 * 1.3).cos() * 4.0).collect(),
    );
    let mut bytes = std::io::Cursor::new(Vec::new());
    dem.write_tiff(&mut bytes).unwrap();
    let said = core.open_file("fine.tif", bytes.into_inner()).unwrap();
    assert!(said.starts_with("Pinned fine.tif: 1 tile from tile (0, 0); its own detail is kept to 8 m"), "{said}");
    let pin = core.app.user_pins().get(TileCoord::new(0, 0)).unwrap().clone();
    let p = core.app.camera.position_m;
    core.app.camera.position_m.y = 1400.0 + 60.0;
    let (mut at8, mut at16) = (None, None);
    for _ in 0..600 {
        shell.frames(&mut core, 1);
        core.app.camera.position_m = p.with_y(1460.0);
        if let (Ok(a), Ok(b)) = (core.app.export_refined(1), core.app.export_refined(0)) {
            (at8, at16) = (Some(a), Some(b));
            break;
        }
    }
    let check = |hf: crate::dem::Heightfield, level: usize| {
        let (s, side) = (hf.spacing_m, crate::world::pins::detail_side(level) as i64);
        let g = hf.geo.expect("placed in the world's frame");
        let (px0, py0) = (((g.origin_m[0] + 16.0) / s).round() as i64, ((16.0 - g.origin_m[1]) / s).round() as i64);
        let own = pin.detail(level).unwrap();
        let mut matched = 0;
        for (k, v) in hf.data.iter().enumerate() {
            let (x, y) = (px0 + (k % hf.width) as i64, py0 + (k / hf.width) as i64);
            if (0..side).contains(&x) && (0..side).contains(&y) {
                assert_eq!(v.to_bits(), own[(y * side + x) as usize].to_bits(), "level {level} pixel ({x}, {y})");
                matched += 1;
            }
        }
        matched
    };
    let (m8, m16) = (check(at8.expect("refined to 8 m over the pin"), 1), check(at16.expect("refined to 16 m"), 0));
    eprintln!("{m8} samples at 8 m and {m16} at 16 m exported over the pin are its own");
    assert!(m8 >= 128 * 128 && m16 >= 128 * 128, "{m8}, {m16}");
}

/// A 16-bit heightmap PNG (this project's export) opened after its JSON sidecar waits with the
/// sidecar's spacing and heights, and Pin pins it like the GeoTIFF of the same terrain: the
/// eye's tile within half a PNG unit of it. Opened alone it waits with answers to give (and
/// can be cancelled); a PNG of another kind is refused with why.
#[test]
fn a_heightmap_png_with_its_sidecar_is_pinned_like_its_geotiff() {
    use crate::dem::formats::Format;
    use crate::grid::TileCoord;
    let mut core = PageCore::new(ShareState { position_m: [2048.0, 900.0, 2048.0], pitch: -0.6, radius_tiles: 1.0, ..ShareState::default() }, start(Ok(())));
    let mut shell = Shell::new(&no_swap);
    shell.frames(&mut core, 1);
    let n = 256;
    let dem = crate::dem::Heightfield::new(n, n, 32.0, (0..n * n).map(|p| 300.0 + (p % n) as f32 * 4.0 + ((p / n) as f32 * 0.1).sin() * 80.0).collect());
    let out = dem.export(Format::Png16, "hm.png").unwrap();
    let side = serde_json::to_vec(&out.sidecar.clone().unwrap()).unwrap();
    let half_unit = (out.sidecar.as_ref().unwrap().max_m - out.sidecar.as_ref().unwrap().min_m) / 65535.0 * 0.5;
    // Alone: it waits for answers; cancelled, nothing is pinned.
    let said = core.open_file("hm.png", out.bytes.clone()).unwrap();
    assert!(said.contains("say its spacing and the heights"), "{said}");
    core.cancel_heightmap();
    assert!(core.heightmap.is_none() && core.pinned.is_none());
    // The sidecar, then the PNG.
    assert!(core.open_file("hm.png.json", side).unwrap().contains("kept for the heightmap PNG"));
    let said = core.open_file("hm.png", out.bytes).unwrap();
    assert!(said.contains("hm.png.json gave its spacing and heights"), "{said}");
    let said = core.pin_heightmap().unwrap();
    assert!(said.starts_with("Pinned hm.png: 4 tiles from tile (0, 0)"), "{said}");
    assert!(core.heightmap.is_none());
    let pinned = TileCoord::new(0, 0);
    for _ in 0..400 {
        if core.app.tile_heights(pinned).is_some() {
            break;
        }
        shell.frames(&mut core, 1);
    }
    let got = core.app.tile_heights(pinned).expect("the pinned tile");
    let want = dem.window(0, 0, 128, 128).data;
    let worst = got.iter().zip(&want).map(|(a, b)| (a - b).abs() as f64).fold(0.0, f64::max);
    assert!(worst <= half_unit + 1e-3, "{worst} m vs half a unit {half_unit} m");
    // A 16-bit RGB PNG is neither a sketch nor a heightmap.
    let mut rgb16 = Vec::new();
    let mut e = png::Encoder::new(&mut rgb16, 1, 1);
    e.set_color(png::ColorType::Rgb);
    e.set_depth(png::BitDepth::Sixteen);
    e.write_header().unwrap().write_image_data(&[0; 6]).unwrap();
    let refused = core.open_file("odd.png", rgb16).unwrap_err();
    assert!(refused.contains("odd.png is a PNG of Rgb at Sixteen") && refused.contains("nor is it a sketch"), "{refused}");
}

/// With `?world=gpu` and a GPU (a second runner stands in for it: the same kernels, so the same
/// bits), each learned tile's network work goes to the GPU in batches (world-work and
/// accept-work to the worker, run-work to the GPU only), and the eye's coarse stand-in and the
/// tiles are the CPU's bit for bit; the world's load and the overlay say "WebGPU" and the
/// GPU's milliseconds a tile. A batch goes in calls of about half a median frame's work: with
/// 2 ms an item and 16 ms frames, the first call has 1 item and the rest at most 4 (some 4),
/// and each batch is accepted once. A GPU that then fails a batch moves the world's networks
/// to the CPU worker for good, saying why in the console and the overlay; every tile is still
/// made.
#[test]
fn with_the_world_on_the_gpu_tiles_come_from_its_batches_bit_for_bit_in_calls_of_half_a_frames_work_and_a_failing_gpu_falls_back_to_the_worker() {
    use crate::grid::TileCoord;
    let share = ShareState { radius_tiles: 1.0, position_m: [2048.0, 3000.0, 2048.0], pitch: -1.2, ..ShareState::default() };
    let mut core = PageCore::new(share, PageStart { gpu: Ok(()), world: TemChoice::Gpu, tem: TemChoice::Cpu, ..start(Ok(())) });
    assert_eq!(*core.world_probe(), Probe::Off, "no probe where the user chose");
    let mut shell = Shell::new(&no_swap);
    shell.gpu = Some((Runner::new(1), 2.0));
    shell.frames(&mut core, 3);
    assert_eq!(core.world_backend(), "WebGPU");
    assert!(matches!(&core.loads.world, Load::Ready { backend, .. } if backend == "WebGPU"), "{:?}", core.loads.world);
    let cpu = LearnedSource::new(std::sync::Arc::new(LearnedModels::load_dir(&weights()).unwrap()), 1);
    let (seed, eye) = (core.app.settings().seed, TileCoord::new(0, 0));
    assert_eq!(core.app.world.coarse(eye).map(|t| t.to_vec()), Some(cpu.eroded_tile(seed, eye).to_vec()), "the eye's coarse stand-in");
    shell.frames(&mut core, 200);
    let s = core.app.stats().clone();
    assert!(s.tiles_pending == 0 && s.tiles_generated >= 9 && s.tile_jobs.failed == 0, "{s:?}");
    let count = |shell: &Shell, target, kind: &str| shell.posted.iter().filter(|(t, k)| *t == target && *k == kind).count();
    let runs = count(&shell, Target::Gpu, "run-work");
    let accepted = count(&shell, Target::Worker, "accept-work");
    assert!(runs >= 2 && accepted >= 2 && accepted < runs && count(&shell, Target::Worker, "run-work") == 0, "{:?}", shell.posted);
    let items = shell.gpu_items.clone();
    assert_eq!(items.len(), runs);
    assert!(items[0] == 1 && items.iter().all(|&k| (1..=4).contains(&k)) && items.contains(&4), "items a call: {items:?}");
    assert_eq!(core.gpu_call_items(), 4);
    let tiles = core.app.drawable_tiles();
    assert!(tiles.len() >= 5, "{tiles:?}");
    for &c in &tiles {
        assert!(core.app.tile_heights(c).unwrap() == &cpu.generate(seed, c, &Neighbourhood::default()).heights[..], "tile {c:?} differs");
    }
    let gpu_ms = core.world_gpu_ms_per_tile().expect("the GPU's ms a tile");
    assert!(gpu_ms >= 2.0, "{gpu_ms}");
    // The stand-in GPU forgets the world's networks: its next batch fails.
    shell.gpu = Some((Runner::new(1), 5.0));
    core.app.camera.position_m += DVec3::new(3.0 * crate::grid::TILE_SIZE_M, 0.0, 0.0);
    shell.frames(&mut core, 200);
    let s = core.app.stats().clone();
    assert!(s.tiles_pending == 0 && s.tile_jobs.failed == 0, "{s:?}");
    assert!(core.world_backend().starts_with("CPU worker (WebGPU failed: a batch failed there: "), "{}", core.world_backend());
    assert!(matches!(&core.loads.world, Load::Ready { backend, .. } if *backend == core.world_backend()));
    assert!(core.console.iter().any(|l| l.contains("cannot run on WebGPU")), "{:?}", core.console);
    assert_eq!(count(&shell, Target::Gpu, "run-work"), runs + 1, "one failed batch, then none");
    let c = core.app.drawable_tiles().into_iter().find(|c| !tiles.contains(c)).expect("a tile made after the GPU failed");
    assert!(core.app.tile_heights(c).unwrap() == &cpu.generate(seed, c, &Neighbourhood::default()).heights[..]);
    assert_eq!(core.message, None);
}

/// The size of the GPU's calls of world network work: none timed yet, one item, whole; at
/// 2 ms an item and 60 frames a second (no frame measured yet), 4 items (half a frame:
/// 8.3 ms), whole; at 1,000 ms an item (about SwiftShader's ×4 window), one item, a ×4 step's
/// in two halves with a frame between them.
#[test]
fn gpu_calls_hold_half_a_median_frame_of_work_and_a_x4_window_goes_in_halves_where_one_item_takes_longer() {
    let mut core = PageCore::new(ShareState::default(), PageStart { gpu: Ok(()), world: TemChoice::Gpu, tem: TemChoice::Cpu, ..start(Ok(())) });
    assert_eq!((core.gpu_call_items(), core.gpu_call_halves()), (1, false));
    core.world_gpu_item_ms = Some(2.0);
    assert_eq!((core.gpu_call_items(), core.gpu_call_halves()), (4, false));
    core.world_gpu_item_ms = Some(1000.0);
    assert_eq!((core.gpu_call_items(), core.gpu_call_halves()), (1, true));
}

/// On a hardware adapter whose GPU passed its self-check (`?world=` not given), the learned
/// world's networks load on the GPU and in the worker; once the first view is complete the
/// probe times a batch of [`WORLD_PROBE_TILES`] TCM tiles on each (a warm-up and three timed
/// runs, run-work on both): answered as 10 s on the GPU, the worker wins and the world's
/// backend says why; answered as 0.001 ms, the GPU keeps them.
#[test]
fn the_world_networks_probe_keeps_them_on_the_faster_backend_once_the_first_view_is_complete() {
    for (gpu_ms, on_gpu) in [(10_000.0, false), (0.001, true)] {
        let share = ShareState { source: SourceKind::Procedural, position_m: [2048.0, 900.0, 2048.0], pitch: -0.6, ..ShareState::default() };
        let mut core = PageCore::new(share, PageStart { gpu: Ok(()), tem: TemChoice::Cpu, ..start(Ok(())) });
        let mut shell = Shell::new(&no_swap);
        shell.gpu = Some((Runner::new(1), gpu_ms / WORLD_PROBE_TILES as f64));
        assert_eq!(*core.world_probe(), Probe::Waiting);
        shell.frames(&mut core, 1);
        assert_eq!(core.world_backend(), "WebGPU", "loaded there before the probe");
        shell.frames(&mut core, 120);
        assert_eq!(core.app.stats().tiles_uncovered, 0);
        let Probe::Done(t) = *core.world_probe() else { panic!("{:?}", core.world_probe()) };
        assert!((t.gpu_ms - gpu_ms).abs() < 1e-9 * gpu_ms && t.cpu_ms > 0.0 && t.cpu_ms < 10_000.0, "{t:?}");
        let runs = |target| shell.posted.iter().filter(|(t, k)| *t == target && *k == "run-work").count();
        assert_eq!((runs(Target::Gpu), runs(Target::Worker)), (1 + TIMED_RUNS, 1 + TIMED_RUNS));
        let want = if on_gpu { "WebGPU".to_string() } else { format!("CPU worker (faster: {})", t.label(&world_probe_unit())) };
        assert_eq!(core.world_backend(), want);
        assert!(core.console.iter().any(|l| l.starts_with("world probe: WebGPU")), "{:?}", core.console);
    }
}

/// A worker that dies while a tile's batch runs on the GPU: the GPU's outputs that come back
/// after it are dropped with the tile (nothing is blamed on the GPU: the world's networks are
/// not said to have failed there), and nothing stays in flight.
#[test]
fn a_worker_that_dies_while_the_gpu_runs_a_batch_does_not_fail_the_gpu() {
    let share = ShareState { radius_tiles: 1.0, ..ShareState::default() };
    let mut core = PageCore::new(share, PageStart { gpu: Ok(()), world: TemChoice::Gpu, tem: TemChoice::Cpu, ..start(Ok(())) });
    let mut shell = Shell::new(&no_swap);
    shell.gpu = Some((Runner::new(1), 5.0));
    shell.frames(&mut core, 1);
    let mut batch = None;
    for _ in 0..10 {
        core.app.frame(&ControlInput::default(), 0.016, [640, 400]);
        core.start_work(shell.clock_ms);
        let mut effects = core.take_effects();
        // Everything but the first batch for the GPU is carried out (the worker answers).
        while !effects.is_empty() {
            for e in effects {
                match e {
                    Effect::Post { target: Target::Gpu, envelope } if batch.is_none() && envelope.request.kind() == "run-work" => batch = Some(envelope),
                    e => shell.carry_out_once(&mut core, vec![e]),
                }
            }
            effects = core.take_effects();
        }
        if batch.is_some() {
            break;
        }
    }
    let batch = batch.expect("a batch posted to the GPU");
    core.deliver(Delivery::WorkerGone { id: 0, why: "out of memory".into() });
    let answer = shell.gpu.as_mut().unwrap().0.handle(batch);
    assert!(matches!(answer.reply, Reply::Outputs { .. }), "{answer:?}");
    core.deliver(Delivery::Answer(answer));
    for e in core.take_effects() {
        if let Effect::Post { target: Target::Worker, envelope } = e {
            core.deliver(Delivery::WorkerGone { id: envelope.id, why: "out of memory".into() });
        }
    }
    assert_eq!(core.in_flight(), 0);
    assert!(!core.world_backend().contains("WebGPU failed"), "{}", core.world_backend());
    assert!(!core.console.iter().any(|l| l.contains("cannot run on WebGPU")), "{:?}", core.console);
    assert_eq!(core.app.source(), SourceKind::Procedural);
}
