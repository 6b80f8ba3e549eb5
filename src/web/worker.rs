//! CPU inference in a Web Worker. The page's own wasm module is instantiated a second time in a
//! module worker, which runs the learned world's networks and the TEM on the CPU kernels
//! ([`crate::models::cpu`]), so the main thread never waits on inference. The main thread
//! ([`CpuWorker`]) posts requests with an id and awaits the matching reply; the worker
//! ([`terrain_worker_message`]) answers them in order, except learned tiles and TEM batches
//! sent with a rest: those it works on in pieces, one request after the other, resting
//! between pieces (and answering other requests meanwhile), so that beside a software
//! rasteriser it leaves the CPU's cores to the frames ([`crate::models::runtime::worker_rest_per_work`]).

use std::cell::{Cell, RefCell};
use std::collections::HashMap;
use std::rc::Rc;

use js_sys::{Array, Float32Array, Object, Reflect, Uint8Array};
use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;
use wasm_bindgen_futures::JsFuture;

use crate::models::sketch::SketchGenCpu;
use crate::models::sketch_vae::{SketchModels, SketchVaeCpu};
use crate::models::tem::{Exec, TemSet};
use crate::sketch::{SKETCH_PX, Sketch, code};
use crate::world::learned::{LearnedModels, LearnedSource};
use crate::world::{Neighbourhood, NoiseParams, ProceduralSource, TileCoord, TileSource};

/// The worker's script: the first message names the page's wasm-bindgen glue and carries the
/// compiled module; the worker instantiates it and hands every later message to
/// [`terrain_worker_message`], in arrival order.
const SCRIPT: &str = r#"
let ready = null;
self.onmessage = (e) => {
  if (ready === null) {
    ready = import(e.data.glue).then(async (m) => { await m.default({ module_or_path: e.data.module }); return m; });
    ready.catch((err) => self.postMessage({ id: 0, error: 'the CPU worker could not start: ' + err }));
    return;
  }
  ready.then((m) => m.terrain_worker_message(e.data));
};
"#;

#[wasm_bindgen]
extern "C" {
    /// The URL of the page's wasm-bindgen glue (the glue module's `import.meta.url`).
    #[wasm_bindgen(thread_local_v2, js_namespace = ["import", "meta"], js_name = url)]
    static GLUE_URL: js_sys::JsString;
}

/// Why a request to the worker failed.
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    /// The worker could not start, or died (the browser's message).
    #[error("{0}")]
    Unavailable(String),
    /// The worker answered with an error (a broken weight file, a bad request).
    #[error("{0}")]
    Failed(String),
}

/// The requests waiting for a reply (their resolve and reject functions, by id), and why the
/// worker is gone once it is.
#[derive(Default)]
struct Waiting {
    waiting: HashMap<u32, (js_sys::Function, js_sys::Function)>,
    dead: Option<String>,
}

type Pending = Rc<RefCell<Waiting>>;

/// Rejects every waiting request with `why` (the worker died or never started).
fn fail_all(pending: &Pending, why: &str) {
    pending.borrow_mut().dead = Some(why.to_string());
    let waiting: Vec<_> = pending.borrow_mut().waiting.drain().collect();
    for (_, (_, reject)) in waiting {
        let _ = reject.call1(&JsValue::NULL, &JsValue::from_str(why));
    }
}

fn set(obj: &Object, key: &str, value: &JsValue) {
    let _ = Reflect::set(obj, &key.into(), value);
}

fn get(obj: &JsValue, key: &str) -> JsValue {
    Reflect::get(obj, &key.into()).unwrap_or(JsValue::UNDEFINED)
}

fn js_error(e: JsValue) -> String {
    e.as_string().unwrap_or_else(|| format!("{e:?}"))
}

/// The main thread's handle on the CPU inference worker (terminated when dropped).
pub struct CpuWorker {
    worker: web_sys::Worker,
    pending: Pending,
    next_id: Cell<u32>,
    _on_message: Closure<dyn FnMut(web_sys::MessageEvent)>,
    _on_error: Closure<dyn FnMut(web_sys::ErrorEvent)>,
}

impl CpuWorker {
    /// Starts the worker. Fails with a message when the browser cannot start a module worker.
    pub async fn start() -> Result<Self, WorkerError> {
        let gone = |e: JsValue| WorkerError::Unavailable(js_error(e));
        let parts = Array::of1(&SCRIPT.into());
        let props = web_sys::BlobPropertyBag::new();
        props.set_type("text/javascript");
        let blob = web_sys::Blob::new_with_str_sequence_and_options(&parts, &props).map_err(gone)?;
        let url = web_sys::Url::create_object_url_with_blob(&blob).map_err(gone)?;
        let opts = web_sys::WorkerOptions::new();
        opts.set_type(web_sys::WorkerType::Module);
        let worker = web_sys::Worker::new_with_options(&url, &opts).map_err(|e| WorkerError::Unavailable(format!("the browser cannot start a module worker: {}", js_error(e))))?;
        let _ = web_sys::Url::revoke_object_url(&url);
        let pending: Pending = Rc::default();
        let p = pending.clone();
        let on_message = Closure::<dyn FnMut(web_sys::MessageEvent)>::new(move |e: web_sys::MessageEvent| {
            let data = e.data();
            let id = get(&data, "id").as_f64().unwrap_or(0.0) as u32;
            let error = get(&data, "error").as_string();
            if id == 0 {
                fail_all(&p, &error.unwrap_or_else(|| "the CPU worker sent a reply without an id".into()));
                return;
            }
            let Some((resolve, reject)) = p.borrow_mut().waiting.remove(&id) else { return };
            let _ = match error {
                // The reply object itself: a worker's answer, unlike a string from `fail_all`.
                Some(_) => reject.call1(&JsValue::NULL, &data),
                None => resolve.call1(&JsValue::NULL, &data),
            };
        });
        worker.set_onmessage(Some(on_message.as_ref().unchecked_ref()));
        let p = pending.clone();
        let on_error = Closure::<dyn FnMut(web_sys::ErrorEvent)>::new(move |e: web_sys::ErrorEvent| {
            fail_all(&p, &format!("the CPU worker failed: {}", e.message()));
        });
        worker.set_onerror(Some(on_error.as_ref().unchecked_ref()));
        let first = Object::new();
        set(&first, "glue", &GLUE_URL.with(|u| u.clone()).into());
        set(&first, "module", &wasm_bindgen::module());
        worker.post_message(&first).map_err(gone)?;
        Ok(Self { worker, pending, next_id: Cell::new(1), _on_message: on_message, _on_error: on_error })
    }

    /// Posts the weight `files` under request `kind` ("load" for the TEM, "load-world" for
    /// the learned world) and returns the reply.
    async fn load(&self, kind: &str, files: &[&[u8]]) -> Result<JsValue, WorkerError> {
        let msg = Object::new();
        set(&msg, "kind", &kind.into());
        let list = Array::new();
        let transfer = Array::new();
        for f in files {
            let bytes = Uint8Array::from(*f);
            transfer.push(&bytes.buffer());
            list.push(&bytes);
        }
        set(&msg, "files", &list);
        self.request(msg, transfer).await
    }

    /// Loads the TEM weights (`files`, level order) into the worker; a broken file is a
    /// [`WorkerError::Failed`] naming it.
    pub async fn load_tem(&self, files: &[Vec<u8>]) -> Result<(), WorkerError> {
        let files: Vec<&[u8]> = files.iter().map(Vec::as_slice).collect();
        self.load("load", &files).await.map(|_| ())
    }

    /// Loads the learned world's weights (the TCM's and the ×4 step's burnpack bytes) into the
    /// worker and returns their hash.
    pub async fn load_world(&self, tcm: &[u8], grow: &[u8]) -> Result<String, WorkerError> {
        let reply = self.load("load-world", &[tcm, grow]).await?;
        get(&reply, "hash").as_string().ok_or_else(|| WorkerError::Failed("the CPU worker's reply has no weights hash".into()))
    }

    /// Makes tile `c` of world `seed` in the worker — procedural with `noise`, else learned —:
    /// its heights (metres) and the worker's milliseconds of work. A learned tile is made in
    /// pieces ([`LearnedSource::prepare`]) with `rest_per_work` ms of rest per ms of work
    /// after each (see [`crate::models::runtime::worker_rest_per_work`]); 0 makes it in one go.
    pub async fn tile(&self, seed: u64, c: TileCoord, noise: Option<NoiseParams>, rest_per_work: f64) -> Result<(Vec<f32>, f64), WorkerError> {
        let msg = Object::new();
        set(&msg, "kind", &"tile".into());
        set(&msg, "rest", &rest_per_work.into());
        set(&msg, "seed", &seed.to_string().into());
        if let Some(n) = noise {
            set(&msg, "noise", &serde_json::to_string(&n).expect("noise parameters serialise").into());
        }
        set(&msg, "i", &c.i.into());
        set(&msg, "j", &c.j.into());
        let reply = self.request(msg, Array::new()).await?;
        let out: Float32Array = get(&reply, "out").dyn_into().map_err(|_| WorkerError::Failed("the CPU worker's reply has no heights".into()))?;
        Ok((out.to_vec(), get(&reply, "ms").as_f64().unwrap_or(0.0)))
    }

    /// Loads the sketch models (the generator's and the VAE's burnpack bytes) into the worker
    /// and returns their hash.
    pub async fn load_sketch(&self, generator: &[u8], vae: &[u8]) -> Result<String, WorkerError> {
        let reply = self.load("load-sketch", &[generator, vae]).await?;
        get(&reply, "hash").as_string().ok_or_else(|| WorkerError::Failed("the CPU worker's reply has no weights hash".into()))
    }

    /// Turns a sketch into terrain in the worker: heights (0–255 scale, 256²) and the
    /// worker's milliseconds.
    pub async fn sketch(&self, sketch: &Sketch) -> Result<(Vec<f32>, f64), WorkerError> {
        let msg = Object::new();
        set(&msg, "kind", &"sketch".into());
        set(&msg, "code", &code::encode(sketch).into());
        let reply = self.request(msg, Array::new()).await?;
        let out: Float32Array = get(&reply, "out").dyn_into().map_err(|_| WorkerError::Failed("the CPU worker's reply has no heights".into()))?;
        Ok((out.to_vec(), get(&reply, "ms").as_f64().unwrap_or(0.0)))
    }

    /// `n` variants of a sketch (seeded), each with its terrain, made in the worker.
    pub async fn variants(&self, sketch: &Sketch, n: usize, seed: u64) -> Result<Vec<(Sketch, Vec<f32>)>, WorkerError> {
        let msg = Object::new();
        set(&msg, "kind", &"variants".into());
        set(&msg, "code", &code::encode(sketch).into());
        set(&msg, "n", &(n as u32).into());
        set(&msg, "seed", &seed.to_string().into());
        let reply = self.request(msg, Array::new()).await?;
        sketches_of(&reply)
    }

    /// The sketch α·a + (1 − α)·b in the VAE's code space, with its terrain, made in the
    /// worker.
    pub async fn blend(&self, a: &Sketch, b: &Sketch, alpha: f32) -> Result<(Sketch, Vec<f32>), WorkerError> {
        let msg = Object::new();
        set(&msg, "kind", &"blend".into());
        set(&msg, "code", &code::encode(a).into());
        set(&msg, "other", &code::encode(b).into());
        set(&msg, "alpha", &alpha.into());
        let reply = self.request(msg, Array::new()).await?;
        sketches_of(&reply)?.pop().ok_or_else(|| WorkerError::Failed("the CPU worker's reply has no sketch".into()))
    }

    /// Posts `msg` (its buffers in `transfer` move to the worker) and waits for the reply.
    async fn request(&self, msg: Object, transfer: Array) -> Result<JsValue, WorkerError> {
        if let Some(why) = &self.pending.borrow().dead {
            return Err(WorkerError::Unavailable(why.clone()));
        }
        let id = self.next_id.get();
        self.next_id.set(id.wrapping_add(1).max(1));
        set(&msg, "id", &id.into());
        let pending = self.pending.clone();
        let promise = js_sys::Promise::new(&mut |resolve, reject| {
            pending.borrow_mut().waiting.insert(id, (resolve, reject));
        });
        if let Err(e) = self.worker.post_message_with_transfer(&msg, &transfer) {
            self.pending.borrow_mut().waiting.remove(&id);
            return Err(WorkerError::Unavailable(js_error(e)));
        }
        JsFuture::from(promise).await.map_err(|e| match get(&e, "error").as_string() {
            Some(msg) => WorkerError::Failed(msg),
            None => WorkerError::Unavailable(js_error(e)),
        })
    }

    /// Why the worker is gone (it failed to start or died), if it is.
    pub fn gone(&self) -> Option<String> {
        self.pending.borrow().dead.clone()
    }

    /// Runs TEM level `level` on `n` windows of side `side` in the worker (as
    /// [`TemSet::enhance_blocking`]) and returns the heights and the worker's milliseconds of
    /// work. With `rest_per_work` > 0 the windows are run one at a time with that much rest
    /// per ms of work after each (see [`crate::models::runtime::worker_rest_per_work`]).
    pub async fn enhance(&self, level: usize, inputs: Vec<f32>, n: usize, side: usize, rest_per_work: f64) -> Result<(Vec<f32>, f64), WorkerError> {
        let msg = Object::new();
        set(&msg, "kind", &"enhance".into());
        set(&msg, "rest", &rest_per_work.into());
        set(&msg, "level", &(level as u32).into());
        set(&msg, "n", &(n as u32).into());
        set(&msg, "side", &(side as u32).into());
        let input = Float32Array::from(inputs.as_slice());
        set(&msg, "input", &input);
        let reply = self.request(msg, Array::of1(&input.buffer())).await?;
        let out: Float32Array = get(&reply, "out").dyn_into().map_err(|_| WorkerError::Failed("the CPU worker's reply has no heights".into()))?;
        Ok((out.to_vec(), get(&reply, "ms").as_f64().unwrap_or(0.0)))
    }
}

/// The sketches (codes) and their terrains (concatenated heights) of a reply.
fn sketches_of(reply: &JsValue) -> Result<Vec<(Sketch, Vec<f32>)>, WorkerError> {
    let bad = |why: &str| WorkerError::Failed(format!("the CPU worker's reply {why}"));
    let codes = Array::from(&get(reply, "codes"));
    let out: Float32Array = get(reply, "out").dyn_into().map_err(|_| bad("has no heights"))?;
    let heights = out.to_vec();
    let n = SKETCH_PX * SKETCH_PX;
    if heights.len() != codes.length() as usize * n {
        return Err(bad("has the wrong number of heights"));
    }
    codes
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let s = code::decode(&c.as_string().unwrap_or_default()).map_err(|e| bad(&e.to_string()))?;
            Ok((s, heights[k * n..(k + 1) * n].to_vec()))
        })
        .collect()
}

impl Drop for CpuWorker {
    fn drop(&mut self) {
        self.worker.terminate();
        fail_all(&self.pending, "the CPU worker was stopped");
    }
}

thread_local! {
    /// The worker's models (set by its "load" request).
    static WORKER_TEM: RefCell<Option<TemSet>> = const { RefCell::new(None) };
    /// The learned world (set by its "load-world" request); its cache of 128 m tiles lives
    /// here.
    static WORKER_WORLD: RefCell<Option<LearnedSource>> = const { RefCell::new(None) };
    /// The sketch generator and VAE (set by the "load-sketch" request).
    static WORKER_SKETCH: RefCell<Option<SketchModels>> = const { RefCell::new(None) };
    /// Requests to answer in pieces with rests, oldest first, and whether they are being
    /// worked on ([`run_paced`]).
    static PACED: RefCell<std::collections::VecDeque<(JsValue, Paced)>> = const { RefCell::new(std::collections::VecDeque::new()) };
    static PACED_RUNNING: Cell<bool> = const { Cell::new(false) };
}

/// A request answered after its pieces of work, with a rest of `rest_per_work` times each
/// piece's length after it.
enum Paced {
    /// A learned tile: its pieces are [`LearnedSource::prepare`]'s.
    Tile { seed: u64, c: TileCoord, rest_per_work: f64 },
    /// TEM level `level` on `n` windows of side `side`, one window per piece.
    Enhance { level: usize, input: Vec<f32>, n: usize, side: usize, rest_per_work: f64 },
}

/// Works through the queued paced requests one after the other: a piece of work, then a rest
/// (other requests are answered meanwhile), until the request is done; then replies with its
/// heights and the milliseconds of work.
async fn run_paced() {
    while let Some((id, job)) = PACED.with(|q| q.borrow_mut().pop_front()) {
        let answer = match job {
            Paced::Tile { seed, c, rest_per_work } => paced_tile(seed, c, rest_per_work).await,
            Paced::Enhance { level, input, n, side, rest_per_work } => paced_enhance(level, &input, n, side, rest_per_work).await,
        };
        reply(id, answer);
    }
    PACED_RUNNING.set(false);
}

/// Learned tile `c` of world `seed`, one [`LearnedSource::prepare`] piece at a time with
/// `rest_per_work` ms of rest per ms of work after each: its heights and the ms of work.
async fn paced_tile(seed: u64, c: TileCoord, rest_per_work: f64) -> Result<Answer, String> {
    let mut work_ms = 0.0;
    loop {
        let (more, ms) = timed(|| with_world(|src| src.prepare(seed, c)));
        work_ms += ms;
        if !more? {
            let (tile, ms) = timed(|| with_world(|src| src.generate(seed, c, &Neighbourhood::default())));
            return Ok(Answer::Heights(tile?.heights, work_ms + ms));
        }
        rest(ms * rest_per_work).await;
    }
}

/// TEM level `level` on the `n` windows of side `side` in `input`, one window at a time with
/// `rest_per_work` ms of rest per ms of work after each: the heights and the ms of work.
async fn paced_enhance(level: usize, input: &[f32], n: usize, side: usize, rest_per_work: f64) -> Result<Answer, String> {
    let (mut out, mut work_ms) = (Vec::with_capacity(input.len()), 0.0);
    for window in input.chunks((input.len() / n.max(1)).max(1)) {
        let (heights, ms) = timed(|| enhance_in_worker(level, window.to_vec(), 1, side));
        out.extend(heights?);
        work_ms += ms;
        rest(ms * rest_per_work).await;
    }
    Ok(Answer::Heights(out, work_ms))
}

/// `f`'s result and how long it took (milliseconds).
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t0 = web_time::Instant::now();
    let out = f();
    (out, t0.elapsed().as_secs_f64() * 1000.0)
}

/// Runs `f` with the worker's learned world.
fn with_world<T>(f: impl FnOnce(&LearnedSource) -> T) -> Result<T, String> {
    WORKER_WORLD.with(|w| w.borrow().as_ref().map(f)).ok_or_else(|| NO_WORLD.to_string())
}

/// Runs TEM level `level` of the worker's models on `n` windows of side `side`.
fn enhance_in_worker(level: usize, input: Vec<f32>, n: usize, side: usize) -> Result<Vec<f32>, String> {
    WORKER_TEM.with(|t| match t.borrow().as_ref() {
        Some(tem) if level < crate::models::tem::LEVELS => tem.enhance_blocking(level, input, n, side),
        Some(_) => Err(format!("no TEM level {level}")),
        None => Err("the CPU worker has no models loaded".into()),
    })
}

/// Resolves after `ms` milliseconds (a timer of the worker's global scope).
async fn rest(ms: f64) {
    let wait = js_sys::Promise::new(&mut |resolve, _| {
        let scope: web_sys::DedicatedWorkerGlobalScope = js_sys::global().unchecked_into();
        let _ = scope.set_timeout_with_callback_and_timeout_and_arguments_0(&resolve, ms.round() as i32);
    });
    let _ = JsFuture::from(wait).await;
}

const NO_WORLD: &str = "the CPU worker has no learned world loaded";

/// Runs `f` with the worker's sketch models.
fn with_sketch<T>(f: impl FnOnce(&SketchGenCpu, &SketchVaeCpu) -> T) -> Result<T, String> {
    WORKER_SKETCH.with(|m| m.borrow().as_ref().map(|m| f(&m.generator, &m.vae))).ok_or_else(|| "the CPU worker has no sketch models loaded".to_string())
}

/// What the worker answers: nothing, inference results (heights, ms), or a weights hash.
enum Answer {
    Nothing,
    Heights(Vec<f32>, f64),
    Hash(String),
    /// Sketches (codes) and their terrains, concatenated.
    Sketches(Vec<String>, Vec<f32>),
}

/// The sketch in field `key` of a request (its code).
fn sketch_arg(msg: &JsValue, key: &str) -> Result<Sketch, String> {
    code::decode(&get(msg, key).as_string().ok_or(format!("the request has no {key}"))?).map_err(|e| e.to_string())
}

/// What a request asks of the worker.
fn handle(msg: &JsValue) -> Result<Answer, String> {
    let files = || -> Vec<Vec<u8>> { Array::from(&get(msg, "files")).iter().map(|f| Uint8Array::new(&f).to_vec()).collect() };
    match get(msg, "kind").as_string().as_deref() {
        Some("load") => {
            let tem = TemSet::from_bytes(files(), &Exec::cpu())?;
            WORKER_TEM.with(|t| *t.borrow_mut() = Some(tem));
            Ok(Answer::Nothing)
        }
        Some("load-world") => {
            let f = files();
            let [tcm, grow] = f.as_slice() else { return Err("load-world needs two weight files".into()) };
            let models = LearnedModels::from_bytes(tcm, grow)?;
            let hash = models.hash.clone();
            WORKER_WORLD.with(|w| *w.borrow_mut() = Some(LearnedSource::new(std::sync::Arc::new(models), 1)));
            Ok(Answer::Hash(hash))
        }
        Some("load-sketch") => {
            let f = files();
            let [generator, vae] = f.as_slice() else { return Err("load-sketch needs two weight files".into()) };
            let models = SketchModels::from_bytes(generator, vae)?;
            let hash = models.hash.clone();
            WORKER_SKETCH.with(|m| *m.borrow_mut() = Some(models));
            Ok(Answer::Hash(hash))
        }
        Some("sketch") => {
            let sketch = sketch_arg(msg, "code")?;
            let (h, ms) = timed(|| with_sketch(|g, _| g.generate(&sketch, &mut Default::default(), 1)));
            Ok(Answer::Heights(h?, ms))
        }
        Some("variants") => {
            let sketch = sketch_arg(msg, "code")?;
            let n = get(msg, "n").as_f64().filter(|n| (1.0..=16.0).contains(n)).ok_or("the request needs 1..16 variants")? as usize;
            let seed: u64 = get(msg, "seed").as_string().and_then(|s| s.parse().ok()).ok_or("the request has no seed")?;
            with_sketch(|g, v| {
                let list = v.variants(&sketch, n, seed, &mut Default::default(), 1);
                let heights = list.iter().flat_map(|s| g.generate(s, &mut Default::default(), 1)).collect();
                Answer::Sketches(list.iter().map(code::encode).collect(), heights)
            })
        }
        Some("blend") => {
            let (a, b) = (sketch_arg(msg, "code")?, sketch_arg(msg, "other")?);
            let alpha = get(msg, "alpha").as_f64().filter(|a| (0.0..=1.0).contains(a)).ok_or("the request needs an alpha in 0..1")? as f32;
            with_sketch(|g, v| {
                let s = v.interpolate(&a, &b, alpha, &mut Default::default(), 1);
                let h = g.generate(&s, &mut Default::default(), 1);
                Answer::Sketches(vec![code::encode(&s)], h)
            })
        }
        Some("tile") => {
            let (seed, c) = tile_request(msg)?;
            let (tile, ms) = timed(|| match get(msg, "noise").as_string() {
                Some(json) => {
                    let noise: NoiseParams = serde_json::from_str(&json).map_err(|e| format!("the request's noise parameters are broken ({e})"))?;
                    Ok(ProceduralSource::new(noise).generate(seed, c, &Neighbourhood::default()))
                }
                None => with_world(|src| src.generate(seed, c, &Neighbourhood::default())),
            });
            Ok(Answer::Heights(tile?.heights, ms))
        }
        Some("enhance") => {
            let (level, n, side, input) = enhance_request(msg)?;
            let (out, ms) = timed(|| enhance_in_worker(level, input.to_vec(), n, side));
            Ok(Answer::Heights(out?, ms))
        }
        other => Err(format!("the CPU worker does not know the request {other:?}")),
    }
}

/// The worker's entry point for one request (called by the worker script, never by the page):
/// loads models or runs inference, and posts the reply `{id, out, ms}` or `{id, error}`. A
/// learned tile or a TEM batch with a rest ([`CpuWorker::tile`], [`CpuWorker::enhance`]) is
/// queued and answered once made.
#[wasm_bindgen]
pub fn terrain_worker_message(msg: JsValue) {
    if let Some(job) = paced(&msg) {
        PACED.with(|q| q.borrow_mut().push_back((get(&msg, "id"), job)));
        if !PACED_RUNNING.replace(true) {
            wasm_bindgen_futures::spawn_local(run_paced());
        }
        return;
    }
    reply(get(&msg, "id"), handle(&msg));
}

/// The paced request in `msg`: a learned tile or a TEM batch with a rest above 0 and every
/// field it needs (else `None`, and [`handle`] answers it at once or says what is wrong).
fn paced(msg: &JsValue) -> Option<Paced> {
    let rest_per_work = get(msg, "rest").as_f64().filter(|r| r.is_finite() && *r > 0.0)?;
    match get(msg, "kind").as_string().as_deref() {
        Some("tile") if get(msg, "noise").is_undefined() => {
            let (seed, c) = tile_request(msg).ok()?;
            Some(Paced::Tile { seed, c, rest_per_work })
        }
        Some("enhance") => {
            let (level, n, side, input) = enhance_request(msg).ok()?;
            (n > 0 && input.length() as usize % n == 0).then(|| Paced::Enhance { level, input: input.to_vec(), n, side, rest_per_work })
        }
        _ => None,
    }
}

/// The world seed and tile of a "tile" request.
fn tile_request(msg: &JsValue) -> Result<(u64, TileCoord), String> {
    let seed: u64 = get(msg, "seed").as_string().and_then(|s| s.parse().ok()).ok_or("the request has no seed")?;
    let coord = |k: &str| get(msg, k).as_f64().filter(|v| v.fract() == 0.0 && v.abs() < 1e9).map(|v| v as i32).ok_or(format!("the request has no tile {k}"));
    Ok((seed, TileCoord::new(coord("i")?, coord("j")?)))
}

/// The TEM level, window count, window side and input heights of an "enhance" request.
fn enhance_request(msg: &JsValue) -> Result<(usize, usize, usize, Float32Array), String> {
    let num = |k: &str| get(msg, k).as_f64().map(|v| v as usize).ok_or(format!("the request has no {k}"));
    let (level, n, side) = (num("level")?, num("n")?, num("side")?);
    let input: Float32Array = get(msg, "input").dyn_into().map_err(|_| "the request has no heights".to_string())?;
    Ok((level, n, side, input))
}

/// Posts the reply to request `id`: `{id, out, ms}`, `{id, hash}`, `{id, out, codes}` or
/// `{id, error}`.
fn reply(id: JsValue, answer: Result<Answer, String>) {
    let reply = Object::new();
    set(&reply, "id", &id);
    let transfer = Array::new();
    match answer {
        Ok(Answer::Heights(out, ms)) => {
            let heights = Float32Array::from(out.as_slice());
            transfer.push(&heights.buffer());
            set(&reply, "out", &heights);
            set(&reply, "ms", &ms.into());
        }
        Ok(Answer::Hash(h)) => set(&reply, "hash", &h.into()),
        Ok(Answer::Sketches(codes, out)) => {
            let heights = Float32Array::from(out.as_slice());
            transfer.push(&heights.buffer());
            set(&reply, "out", &heights);
            set(&reply, "codes", &codes.iter().map(|c| JsValue::from_str(c)).collect::<Array>());
        }
        Ok(Answer::Nothing) => {}
        Err(e) => set(&reply, "error", &e.into()),
    }
    let scope: web_sys::DedicatedWorkerGlobalScope = js_sys::global().unchecked_into();
    let _ = scope.post_message_with_transfer(&reply, &transfer);
}
