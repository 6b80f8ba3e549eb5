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
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(url);
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
    shell.export(Format::Png16);
    assert!(shell.core.message.take().unwrap_or_default().starts_with("Nothing to export yet"));
    let ctx = egui::Context::default();
    for _ in 0..200 {
        frames(&mut shell, &platform, &ctx, 1);
        if shell.core.app.stats().tiles_pending == 0 {
            break;
        }
    }
    shell.export(Format::Png16);
    shell.export(Format::Glb);
    let downloads = platform.downloads.borrow().clone();
    let names: Vec<&str> = downloads.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["terrain-procedural-7.png", "terrain-procedural-7.png.json", "terrain-procedural-7.glb"], "{:?}", shell.core.message);
    let png = Heightfield::read_png(std::io::Cursor::new(platform.files.borrow()[0].clone()), crate::dem::PngScale::default(), 32.0).unwrap();
    assert_eq!((png.width, png.height), (5 * crate::grid::coord::TILE_SAMPLES, 5 * crate::grid::coord::TILE_SAMPLES));
    let side: serde_json::Value = serde_json::from_slice(&platform.files.borrow()[1]).unwrap();
    assert_eq!(side["spacing_m"], 32.0);
    assert!(downloads[2].1 > 1_000_000, "a mesh of 640² vertices: {} bytes", downloads[2].1);
}
