//! The page's frames driven natively: files from `weights/`, the CPU worker on a thread, no
//! GPU, the address bar a string.

use std::cell::{Cell, RefCell};
use std::rc::Rc;

use super::*;
use crate::dem::Heightfield;
use crate::jobs::native::NativeRunner;
use crate::jobs::protocol::{Answer, Envelope};

/// The thread runner, which the test can take for dead.
struct TestWorker {
    runner: NativeRunner,
    dead: RefCell<Option<String>>,
    /// Requests posted to it after it died.
    calls_when_dead: Cell<u32>,
}

impl Port for TestWorker {
    async fn call(&self, env: &Envelope) -> Result<Answer, String> {
        if let Some(why) = self.gone() {
            self.calls_when_dead.set(self.calls_when_dead.get() + 1);
            return Err(why);
        }
        self.runner.call(env).map_err(|e| e.to_string())
    }

    fn gone(&self) -> Option<String> {
        self.dead.borrow().clone()
    }
}

/// A platform whose tasks run when the test says, whose files are `weights/`, and whose
/// address bar is a string.
#[derive(Default)]
struct TestPlatform {
    tasks: RefCell<Vec<Task>>,
    fragment: RefCell<String>,
    fragments_written: Cell<u32>,
    downloads: RefCell<Vec<(String, usize)>>,
    files: RefCell<Vec<Vec<u8>>>,
    warnings: RefCell<Vec<String>>,
}

impl TestPlatform {
    /// Runs the spawned tasks (and those they spawn) to their end: the thread runner answers
    /// without waiting on anything else.
    fn run_tasks(&self) {
        let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
        loop {
            let tasks = std::mem::take(&mut *self.tasks.borrow_mut());
            if tasks.is_empty() {
                return;
            }
            for mut t in tasks {
                while t.as_mut().poll(&mut cx).is_pending() {}
            }
        }
    }
}

impl Platform for TestPlatform {
    type Worker = TestWorker;

    fn spawn(&self, task: Task) {
        self.tasks.borrow_mut().push(task);
    }

    fn fetch(&self, url: &str) -> Fetching {
        let path = crate::repo_root().join(url);
        let url = url.to_string();
        Box::pin(async move { std::fs::read(path).map_err(|e| format!("{url}: {e}")) })
    }

    fn fragment(&self) -> String {
        self.fragment.borrow().clone()
    }

    fn set_fragment(&self, fragment: &str) {
        *self.fragment.borrow_mut() = fragment.to_string();
        self.fragments_written.set(self.fragments_written.get() + 1);
    }

    fn address(&self) -> String {
        "http://localhost:8080/".into()
    }

    fn warn(&self, note: &str) {
        self.warnings.borrow_mut().push(note.into());
    }

    fn download(&self, name: &str, bytes: &[u8], _mime: &str) -> Result<(), String> {
        self.downloads.borrow_mut().push((name.into(), bytes.len()));
        self.files.borrow_mut().push(bytes.to_vec());
        Ok(())
    }

    fn pick_file(&self, _accept: &str, _max_bytes: f64, slot: FileSlot) -> Result<(), String> {
        *slot.borrow_mut() = Some(Picked { name: "x.png".into(), bytes: Err(Refused::Unreadable("no file in this test".into())) });
        Ok(())
    }

    fn read_dropped(&self, file: egui::DroppedFileHandle, max_bytes: f64, landed: Rc<RefCell<Vec<Picked>>>) {
        let name = file.path().display().to_string();
        let bytes = file.bytes().map_err(Refused::Unreadable).and_then(|b| if b.len() as f64 > max_bytes { Err(Refused::TooBig(b.len() as f64)) } else { Ok(b) });
        landed.borrow_mut().push(Picked { name, bytes });
    }
}

/// A file dropped on the test page.
#[derive(Debug)]
struct TestFile(std::path::PathBuf, Vec<u8>);

impl egui::DroppedFile for TestFile {
    fn path(&self) -> &std::path::Path {
        &self.0
    }

    fn bytes(&self) -> Result<Vec<u8>, String> {
        Ok(self.1.clone())
    }
}

/// One frame of 1280×800 points with `name` (holding `bytes`) dropped on the page.
fn drop_file(shell: &mut PageShell<TestPlatform>, platform: &TestPlatform, ctx: &egui::Context, name: &str, bytes: Vec<u8>) {
    let input = egui::RawInput {
        screen_rect: Some(egui::Rect::from_min_size(egui::Pos2::ZERO, egui::vec2(1280.0, 800.0))),
        dropped_files: vec![std::sync::Arc::new(TestFile(name.into(), bytes))],
        ..Default::default()
    };
    ctx.run_ui(input, |ui| shell.frame(ui, None)).textures_delta.clear();
    platform.run_tasks();
}

/// A page opened at `fragment` on the test platform, with a worker thread and no GPU.
fn page(fragment: &str) -> (PageShell<TestPlatform>, Rc<TestPlatform>, Rc<Runners<TestWorker>>) {
    let platform = Rc::new(TestPlatform::default());
    *platform.fragment.borrow_mut() = fragment.into();
    let worker = Rc::new(TestWorker { runner: NativeRunner::spawn(1), dead: RefCell::new(None), calls_when_dead: Cell::new(0) });
    let shell = PageShell::start(platform.clone(), Err("no GPU in this test".into()), ("test".into(), false), Ok(worker), "", None);
    let runners = shell.runners().clone();
    (shell, platform, runners)
}

/// Draws `n` frames of 1280×800 points, running the tasks each frame spawned.
fn frames(shell: &mut PageShell<TestPlatform>, platform: &TestPlatform, ctx: &egui::Context, n: usize) {
    for _ in 0..n {
        let input = egui::RawInput { screen_rect: Some(egui::Rect::from_min_size(egui::Pos2::ZERO, egui::vec2(1280.0, 800.0))), ..Default::default() };
        // No renderer here takes the font atlas: its upload is dropped on purpose.
        ctx.run_ui(input, |ui| shell.frame(ui, None)).textures_delta.clear();
        platform.run_tasks();
    }
}

/// Opened at the default view, the shell's frames load the learned world's models through the
/// platform's fetches, have its tiles made on the worker thread, answer the tile probe with the
/// tile's 32² heights as the core holds them, write the view into the address bar and publish
/// statistics JSON that names the learned source.
#[test]
fn frames_load_the_learned_world_make_its_tiles_and_write_the_link() {
    let (mut shell, platform, _runners) = page("");
    let ctx = egui::Context::default();
    shell.probes.borrow_mut().tile = (Some(TileCoord::new(0, 0)), None);
    for _ in 0..200 {
        frames(&mut shell, &platform, &ctx, 1);
        if shell.probes.borrow().tile.1.is_some() {
            break;
        }
    }
    let probe = shell.probes.borrow().tile.1.clone().expect("the probed tile arrived within 200 frames");
    let n = crate::grid::coord::TILE_SAMPLES;
    assert_eq!(probe.len(), n * n);
    assert_eq!(Some(probe.as_slice()), shell.core.app.tile_heights(TileCoord::new(0, 0)));
    let stats: serde_json::Value = serde_json::from_str(&shell.probes.borrow().stats_json).unwrap();
    assert!(stats["source"].as_str().unwrap().starts_with("learned (TCM "), "{}", stats["source"]);
    assert!(stats["stats"]["tiles_generated"].as_u64().unwrap() >= 1);
    assert!(platform.fragment().contains("seed="), "{}", platform.fragment());
    assert!(platform.fragments_written.get() >= 1);
    assert!(shell.core.message.is_none(), "{:?}", shell.core.message);
}

/// A fragment the user types into the address bar is followed on the next frame (the world's
/// seed changes to the typed one); no frame runs while the page is paused; a worker found dead
/// between frames is noticed without any request: the core falls back to the procedural world
/// and says so.
#[test]
fn a_typed_fragment_is_followed_paused_frames_do_not_run_and_a_dead_worker_is_noticed() {
    let (mut shell, platform, runners) = page("");
    let ctx = egui::Context::default();
    frames(&mut shell, &platform, &ctx, 3);
    let mut typed = shell.core.app.share_state();
    typed.seed = 4242;
    *platform.fragment.borrow_mut() = typed.to_fragment();
    frames(&mut shell, &platform, &ctx, 1);
    assert_eq!(shell.core.app.settings().seed, 4242);
    let frames_before = shell.core.app.stats().frames;
    shell.probes.borrow_mut().set_paused(true);
    frames(&mut shell, &platform, &ctx, 3);
    assert_eq!(shell.core.app.stats().frames, frames_before, "no frame runs while paused");
    shell.probes.borrow_mut().set_paused(false);
    frames(&mut shell, &platform, &ctx, 1);
    assert_eq!(shell.core.app.stats().frames, frames_before + 1);
    *runners.worker.as_ref().unwrap().dead.borrow_mut() = Some("the test stopped it".into());
    frames(&mut shell, &platform, &ctx, 2);
    assert_eq!(runners.worker.as_ref().unwrap().calls_when_dead.get(), 0, "noticed before any request was posted to it");
    assert!(shell.core.worker().is_err());
    assert_eq!(shell.core.app.source(), crate::world::SourceKind::Procedural);
    let message = shell.core.message.clone().unwrap_or_default();
    assert!(message.contains("the test stopped it"), "{message}");
}

/// A picked sketch PNG becomes the sketch; one over 2 MB is refused by its size with the size
/// in the message; bytes that are not a PNG and an unreadable file are said with the file's
/// name.
#[test]
fn picked_files_become_sketches_or_clear_messages() {
    let mut png = Vec::new();
    let sketch = crate::sketch::examples::first().1;
    sketch.write_png(&mut png).unwrap();
    let pick = |bytes| sketch_from_file(Picked { name: "s.png".into(), bytes });
    assert_eq!(pick(Ok(png)).unwrap(), sketch);
    assert_eq!(pick(Err(Refused::TooBig(3.0 * 1024.0 * 1024.0))).unwrap_err(), "s.png is 3.0 MB; a sketch PNG (256×256 pixels) is at most 2 MB");
    assert!(pick(Ok(b"not a png".to_vec())).unwrap_err().starts_with("s.png: "));
    assert_eq!(pick(Err(Refused::Unreadable("gone".into()))).unwrap_err(), "s.png could not be read: gone");
}

/// Export from the page: the settled procedural view (radius 2) downloads as a 16-bit PNG of
/// its 5 × 5 made tiles (640² samples at 32 m) and the PNG's sidecar, and as a binary glTF;
/// before any tile is made it says so instead.
#[test]
fn the_view_exports_as_png16_with_its_sidecar_and_as_glb() {
    use crate::dem::formats::Format;
    let (mut shell, platform, _runners) = page("#v=2&seed=7&src=procedural&cam=2048,2500,2048,0.9,-0.3&r=2&lod=6");
    let ask = |format| crate::ui::ExportAsk { format, level: None, pow2_plus_1: false };
    shell.export(ask(Format::Png16));
    assert!(shell.core.message.take().unwrap_or_default().starts_with("Nothing to export yet"));
    let ctx = egui::Context::default();
    for _ in 0..200 {
        frames(&mut shell, &platform, &ctx, 1);
        if shell.core.app.stats().tiles_pending == 0 {
            break;
        }
    }
    shell.export(ask(Format::Png16));
    shell.export(ask(Format::Glb));
    let downloads = platform.downloads.borrow().clone();
    let names: Vec<&str> = downloads.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["terrain-procedural-7-32m.png", "terrain-procedural-7-32m.png.json", "terrain-procedural-7-32m.glb"], "{:?}", shell.core.message);
    let png = Heightfield::read_png(std::io::Cursor::new(platform.files.borrow()[0].clone()), crate::dem::PngScale::default(), 32.0).unwrap();
    assert_eq!((png.width, png.height), (5 * crate::grid::coord::TILE_SAMPLES, 5 * crate::grid::coord::TILE_SAMPLES));
    let side: serde_json::Value = serde_json::from_slice(&platform.files.borrow()[1]).unwrap();
    assert_eq!(side["spacing_m"], 32.0);
    assert!(downloads[2].1 > 1_000_000, "a mesh of 640² vertices: {} bytes", downloads[2].1);
}

/// Files dropped on the page are opened by what they are. A GeoTIFF is pinned around the eye
/// in the learned world; the world saved as a bundle and dropped on a fresh page opens the
/// same world: its view, the pinned tile bit for bit and the learned tile beside it as the
/// first page made it. A sketch PNG takes the page to the sketch world with that sketch; a
/// file of another kind says what can be dropped and changes nothing.
#[test]
fn dropped_files_pin_a_geotiff_open_a_saved_world_bundle_and_a_sketch() {
    let fragment = "#v=2&seed=3&src=tcm&cam=2048,900,2048,0,-0.6&r=1&lod=6";
    let (mut shell, platform, _runners) = page(fragment);
    let ctx = egui::Context::default();
    let settle = |shell: &mut PageShell<TestPlatform>, tiles: &[TileCoord]| {
        for _ in 0..400 {
            frames(shell, &platform, &ctx, 1);
            if shell.core.loads.world.is_ready() && tiles.iter().all(|&c| shell.core.app.tile_heights(c).is_some()) {
                return;
            }
        }
        panic!("tiles {tiles:?} not made: {:?}", shell.core.app.stats());
    };
    let (pinned, beside) = (TileCoord::new(0, 0), TileCoord::new(-1, 0));
    settle(&mut shell, &[]);
    assert!(shell.core.save_world().is_none(), "nothing pinned: no bundle");
    let n = 256;
    let dem = Heightfield::new(n, n, 32.0, (0..n * n).map(|p| 900.0 + (p % n) as f32 * 2.0 + ((p / n) as f32 * 0.3).cos() * 60.0).collect());
    let mut tif = std::io::Cursor::new(Vec::new());
    dem.write_tiff(&mut tif).unwrap();
    drop_file(&mut shell, &platform, &ctx, "mine.tif", tif.into_inner());
    assert!(shell.core.message.clone().unwrap_or_default().starts_with("Pinned mine.tif: 4 tiles"), "{:?}", shell.core.message);
    settle(&mut shell, &[pinned, beside]);
    let first: Vec<Vec<f32>> = [pinned, beside].iter().map(|&c| shell.core.app.tile_heights(c).unwrap().to_vec()).collect();
    assert_eq!(first[0], dem.window(0, 0, 128, 128).data, "the pinned tile is the GeoTIFF's");
    let bundle = shell.core.save_world().expect("a bundle of the pinned world");
    // A fresh page (another seed, elsewhere) opens the bundle: the same world and view.
    let (mut other, platform2, _r2) = page("#v=2&seed=99&src=tcm&cam=90000,3000,0,0,-0.5&r=1&lod=6");
    let ctx2 = egui::Context::default();
    for _ in 0..400 {
        frames(&mut other, &platform2, &ctx2, 1);
        if other.core.loads.world.is_ready() {
            break;
        }
    }
    drop_file(&mut other, &platform2, &ctx2, crate::share::bundle::FILE_NAME, bundle);
    assert!(other.core.message.clone().unwrap_or_default().starts_with("Opened terrain-world.json.gz: its world and view, with 4 pinned tiles"), "{:?}", other.core.message);
    assert_eq!((other.core.app.settings().seed, other.core.app.camera.position_m.x), (3, 2048.0));
    for _ in 0..400 {
        frames(&mut other, &platform2, &ctx2, 1);
        if [pinned, beside].iter().all(|&c| other.core.app.tile_heights(c).is_some()) {
            break;
        }
    }
    for (k, c) in [pinned, beside].into_iter().enumerate() {
        let got = other.core.app.tile_heights(c).expect("made on the second page");
        assert!(got.iter().zip(&first[k]).all(|(a, b)| a.to_bits() == b.to_bits()), "tile {c:?} differs from the first page's");
    }
    // A sketch PNG: the sketch world, showing it.
    let sketch = crate::sketch::examples::all().swap_remove(2).1;
    let mut png = Vec::new();
    sketch.write_png(&mut png).unwrap();
    drop_file(&mut other, &platform2, &ctx2, "mine.png", png);
    assert_eq!(other.core.app.settings().source, crate::world::SourceKind::Sketch);
    assert_eq!(other.core.app.canvas.sketch(), &sketch);
    // Anything else.
    let seed = other.core.app.settings().seed;
    drop_file(&mut other, &platform2, &ctx2, "notes.txt", b"hello".to_vec());
    assert_eq!(other.core.message.clone().unwrap_or_default(), "notes.txt: drop a GeoTIFF or a heightmap PNG to pin, a sketch PNG, or a world bundle (.json.gz)");
    assert_eq!((other.core.app.settings().seed, other.core.app.settings().source), (seed, crate::world::SourceKind::Sketch));
}

/// A page started again after a lost device keeps the terrain that was pinned: its core names
/// it, the note is shown, and the pinned tile arrives from the worker as pinned, bit for bit.
#[test]
fn a_page_started_again_after_a_lost_device_keeps_the_pinned_terrain() {
    let platform = Rc::new(TestPlatform::default());
    let worker = Rc::new(TestWorker { runner: NativeRunner::spawn(1), dead: RefCell::new(None), calls_when_dead: Cell::new(0) });
    let n = crate::grid::coord::TILE_SAMPLES;
    let heights: Vec<f32> = (0..n * n).map(|p| 1200.0 + (p % n) as f32 * 1.5 - (p / n) as f32).collect();
    let mut pins = crate::world::pins::Pins::new();
    pins.insert(TileCoord::new(0, 0), heights.clone()).unwrap();
    let share = ShareState::from_fragment("v=2&seed=3&src=tcm&cam=2048,900,2048,0,-0.6&r=1&lod=6").unwrap();
    let kept = crate::app::page::Kept { share, note: "the device was lost".into(), pinned: Some(("mine.tif".into(), pins)) };
    let mut shell = PageShell::start(platform.clone(), Err("no GPU in this test".into()), ("test".into(), false), Ok(worker), "", Some(kept));
    assert_eq!(shell.core.pinned, Some(("mine.tif".to_string(), 1)));
    assert_eq!(shell.core.message.as_deref(), Some("the device was lost"));
    let ctx = egui::Context::default();
    for _ in 0..400 {
        frames(&mut shell, &platform, &ctx, 1);
        if shell.core.loads.world.is_ready() && shell.core.app.tile_heights(TileCoord::new(0, 0)).is_some() {
            break;
        }
    }
    let got = shell.core.app.tile_heights(TileCoord::new(0, 0)).expect("the pinned tile made");
    assert!(got.iter().zip(&heights).all(|(a, b)| a.to_bits() == b.to_bits()), "the pinned tile is not the kept pin");
}
