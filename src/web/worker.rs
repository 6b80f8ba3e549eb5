//! The CPU worker's transport. The page's own wasm module is instantiated a second time in a
//! module worker, which answers the protocol's requests with [`Runner`] (bytes in, bytes out,
//! buffers transferred). Tiles and TEM batches are made in pieces with the rest the request
//! asks for between them. A trap in the worker is caught by its script and reported, so the
//! page sees a dead worker instead of a reply that never comes.

use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;

use js_sys::{Array, Object, Reflect, Uint8Array};
use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;
use wasm_bindgen_futures::JsFuture;

use crate::app::runners::Port;
use crate::jobs::protocol::{Answer, Envelope};
use crate::jobs::runner::Queue;

/// The worker's script: the first message carries the glue's URL and the compiled module;
/// later messages are `{id, bytes}` requests. A trap is reported as `{id, trap}`.
const SCRIPT: &str = r#"
let ready = null;
self.onmessage = (e) => {
  if (ready === null) {
    ready = import(e.data.glue).then(async (m) => { await m.default({ module_or_path: e.data.module }); return m; });
    ready.catch((err) => self.postMessage({ id: 0, trap: 'the CPU worker could not start: ' + err }));
    return;
  }
  const id = e.data.id;
  ready.then((m) => m.terrain_worker_message(e.data.bytes)).catch((err) => self.postMessage({ id, trap: 'the CPU worker failed: ' + err }));
};
"#;

#[wasm_bindgen]
extern "C" {
    /// The URL of the page's wasm-bindgen glue (the glue module's `import.meta.url`).
    #[wasm_bindgen(thread_local_v2, js_namespace = ["import", "meta"], js_name = url)]
    static GLUE_URL: js_sys::JsString;
}

/// The requests waiting for a reply (their resolve functions, by id), and why the worker is
/// gone once it is.
#[derive(Default)]
struct Waiting {
    waiting: HashMap<u32, (js_sys::Function, js_sys::Function)>,
    dead: Option<String>,
}

/// Marks the worker dead and rejects every waiting request with `why`.
fn fail_all(pending: &Rc<RefCell<Waiting>>, why: &str) {
    pending.borrow_mut().dead.get_or_insert_with(|| why.to_string());
    let waiting: Vec<_> = pending.borrow_mut().waiting.drain().collect();
    for (_, (_, reject)) in waiting {
        let _ = reject.call1(&JsValue::NULL, &JsValue::from_str(why));
    }
}

fn js_error(e: JsValue) -> String {
    e.as_string().unwrap_or_else(|| format!("{e:?}"))
}

/// The main thread's handle on the CPU worker (terminated when dropped).
pub struct CpuWorker {
    worker: web_sys::Worker,
    pending: Rc<RefCell<Waiting>>,
    _on_message: Closure<dyn FnMut(web_sys::MessageEvent)>,
    _on_error: Closure<dyn FnMut(web_sys::ErrorEvent)>,
}

impl CpuWorker {
    /// Starts the worker, or says why the browser cannot.
    pub fn start() -> Result<Self, String> {
        let parts = Array::of1(&SCRIPT.into());
        let props = web_sys::BlobPropertyBag::new();
        props.set_type("text/javascript");
        let blob = web_sys::Blob::new_with_str_sequence_and_options(&parts, &props).map_err(js_error)?;
        let url = web_sys::Url::create_object_url_with_blob(&blob).map_err(js_error)?;
        let opts = web_sys::WorkerOptions::new();
        opts.set_type(web_sys::WorkerType::Module);
        let worker = web_sys::Worker::new_with_options(&url, &opts).map_err(|e| format!("the browser cannot start a module worker: {}", js_error(e)))?;
        let _ = web_sys::Url::revoke_object_url(&url);
        let pending: Rc<RefCell<Waiting>> = Rc::default();
        let p = pending.clone();
        let on_message = Closure::<dyn FnMut(web_sys::MessageEvent)>::new(move |e: web_sys::MessageEvent| {
            let data = e.data();
            if let Ok(bytes) = data.clone().dyn_into::<Uint8Array>() {
                let id = Answer::peek_id(&bytes.subarray(0, 8.min(bytes.length())).to_vec()).unwrap_or(0);
                if let Some((resolve, _)) = p.borrow_mut().waiting.remove(&id) {
                    let _ = resolve.call1(&JsValue::NULL, &bytes);
                }
                return;
            }
            let trap = Reflect::get(&data, &"trap".into()).ok().and_then(|t| t.as_string());
            fail_all(&p, &trap.unwrap_or_else(|| "the CPU worker sent a message that is not a reply".into()));
        });
        worker.set_onmessage(Some(on_message.as_ref().unchecked_ref()));
        let p = pending.clone();
        let on_error = Closure::<dyn FnMut(web_sys::ErrorEvent)>::new(move |e: web_sys::ErrorEvent| fail_all(&p, &format!("the CPU worker failed: {}", e.message())));
        worker.set_onerror(Some(on_error.as_ref().unchecked_ref()));
        let first = Object::new();
        let _ = Reflect::set(&first, &"glue".into(), &GLUE_URL.with(|u| u.clone()).into());
        let _ = Reflect::set(&first, &"module".into(), &wasm_bindgen::module());
        worker.post_message(&first).map_err(js_error)?;
        Ok(Self { worker, pending, _on_message: on_message, _on_error: on_error })
    }
}

impl Port for CpuWorker {
    /// Why the worker is gone, if it is.
    fn gone(&self) -> Option<String> {
        self.pending.borrow().dead.clone()
    }

    /// Posts `env` (its bytes transferred) and waits for the answer; `Err` when the worker is
    /// gone (why).
    async fn call(&self, env: &Envelope) -> Result<Answer, String> {
        if let Some(why) = self.gone() {
            return Err(why);
        }
        let bytes = Uint8Array::from(env.encode().as_slice());
        let msg = Object::new();
        let _ = Reflect::set(&msg, &"id".into(), &env.id.into());
        let _ = Reflect::set(&msg, &"bytes".into(), &bytes);
        let pending = self.pending.clone();
        let promise = js_sys::Promise::new(&mut |resolve, reject| {
            pending.borrow_mut().waiting.insert(env.id, (resolve, reject));
        });
        if let Err(e) = self.worker.post_message_with_transfer(&msg, &Array::of1(&bytes.buffer())) {
            self.pending.borrow_mut().waiting.remove(&env.id);
            return Err(js_error(e));
        }
        let reply = JsFuture::from(promise).await.map_err(js_error)?;
        Answer::decode(&Uint8Array::new(&reply).to_vec()).map_err(|e| e.to_string())
    }
}

impl Drop for CpuWorker {
    fn drop(&mut self) {
        self.worker.terminate();
        fail_all(&self.pending, "the CPU worker was stopped");
    }
}

thread_local! {
    /// The worker's runner and the tasks it makes in pieces (one kernel thread: the worker is
    /// one thread).
    static QUEUE: RefCell<Queue> = RefCell::new(Queue::new(1));
}

/// The worker's entry point for one request (called by the worker script, never by the page):
/// answers it now, or queues its pieces and makes them ([`make_tasks`]).
#[wasm_bindgen]
pub fn terrain_worker_message(bytes: Uint8Array) {
    let (answer, start) = QUEUE.with(|q| q.borrow_mut().accept_bytes(&bytes.to_vec()));
    if let Some(a) = answer {
        post(&a);
    }
    if start {
        wasm_bindgen_futures::spawn_local(make_tasks());
    }
}

/// Makes the queued tasks a piece at a time, resting as each asks (other requests are
/// answered meanwhile).
async fn make_tasks() {
    while let Some((answer, rest_ms)) = QUEUE.with(|q| q.borrow_mut().next_piece()) {
        if let Some(a) = answer {
            post(&a);
        }
        if rest_ms > 0.0 {
            rest(rest_ms).await;
        }
    }
}

/// Posts an answer to the page (its buffer transferred).
fn post(a: &Answer) {
    let bytes = Uint8Array::from(a.encode().as_slice());
    let scope: web_sys::DedicatedWorkerGlobalScope = js_sys::global().unchecked_into();
    let _ = scope.post_message_with_transfer(&bytes, &Array::of1(&bytes.buffer()));
}

/// Resolves after `ms` milliseconds (a timer of the worker's global scope).
async fn rest(ms: f64) {
    let wait = js_sys::Promise::new(&mut |resolve, _| {
        let scope: web_sys::DedicatedWorkerGlobalScope = js_sys::global().unchecked_into();
        let _ = scope.set_timeout_with_callback_and_timeout_and_arguments_0(&resolve, ms.round() as i32);
    });
    let _ = JsFuture::from(wait).await;
}
