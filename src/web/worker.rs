//! The CPU worker's transport. The page's own wasm module is instantiated a second time in a
//! module worker, which answers the protocol's requests with [`Runner`] (bytes in, bytes out,
//! buffers transferred). Tiles and TEM batches are made in pieces with the rest the request
//! asks for between them. A trap in the worker is caught by its script and reported, so the
//! page sees a dead worker instead of a reply that never comes.

use std::cell::RefCell;
use std::rc::Rc;

use js_sys::{Array, Object, Reflect, Uint8Array};
use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;

use crate::app::runners::Port;
use crate::jobs::calls::Calls;
use crate::jobs::protocol::{Answer, Envelope};
use crate::jobs::runner::Queue;

/// The worker's script (`www/cpu_worker.js`): it loads the module, hands each request to
/// [`terrain_worker_message`] and reports a trap.
const SCRIPT: &str = include_str!("../../www/cpu_worker.js");

#[wasm_bindgen]
extern "C" {
    /// The URL of the page's wasm-bindgen glue (the glue module's `import.meta.url`).
    #[wasm_bindgen(thread_local_v2, js_namespace = ["import", "meta"], js_name = url)]
    static GLUE_URL: js_sys::JsString;
}

fn js_error(e: JsValue) -> String {
    e.as_string().unwrap_or_else(|| format!("{e:?}"))
}

/// The main thread's handle on the CPU worker (terminated when dropped).
pub struct CpuWorker {
    worker: web_sys::Worker,
    calls: Rc<RefCell<Calls>>,
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
        let calls: Rc<RefCell<Calls>> = Rc::default();
        let c = calls.clone();
        let on_message = Closure::<dyn FnMut(web_sys::MessageEvent)>::new(move |e: web_sys::MessageEvent| match e.data().dyn_into::<Uint8Array>() {
            Ok(bytes) => c.borrow_mut().reply(bytes.to_vec()),
            Err(data) => {
                let trap = Reflect::get(&data, &"trap".into()).ok().and_then(|t| t.as_string());
                c.borrow_mut().fail_all(&trap.unwrap_or_else(|| "the CPU worker sent a message that is not a reply".into()));
            }
        });
        worker.set_onmessage(Some(on_message.as_ref().unchecked_ref()));
        let c = calls.clone();
        let on_error = Closure::<dyn FnMut(web_sys::ErrorEvent)>::new(move |e: web_sys::ErrorEvent| c.borrow_mut().fail_all(&format!("the CPU worker failed: {}", e.message())));
        worker.set_onerror(Some(on_error.as_ref().unchecked_ref()));
        let first = Object::new();
        let _ = Reflect::set(&first, &"glue".into(), &GLUE_URL.with(|u| u.clone()).into());
        let _ = Reflect::set(&first, &"module".into(), &wasm_bindgen::module());
        worker.post_message(&first).map_err(js_error)?;
        Ok(Self { worker, calls, _on_message: on_message, _on_error: on_error })
    }
}

impl Port for CpuWorker {
    /// Why the worker is gone, if it is.
    fn gone(&self) -> Option<String> {
        self.calls.borrow().gone()
    }

    /// Posts `env` (its bytes transferred) and waits for the answer; `Err` when the worker is
    /// gone (why).
    async fn call(&self, env: &Envelope) -> Result<Answer, String> {
        let reply = self.calls.borrow_mut().wait(env.id);
        if self.gone().is_none() {
            let bytes = Uint8Array::from(env.encode().as_slice());
            let msg = Object::new();
            let _ = Reflect::set(&msg, &"id".into(), &env.id.into());
            let _ = Reflect::set(&msg, &"bytes".into(), &bytes);
            if let Err(e) = self.worker.post_message_with_transfer(&msg, &Array::of1(&bytes.buffer())) {
                self.calls.borrow_mut().drop_call(env.id, js_error(e));
            }
        }
        Answer::decode(&reply.await?).map_err(|e| e.to_string())
    }
}

impl Drop for CpuWorker {
    fn drop(&mut self) {
        self.worker.terminate();
        self.calls.borrow_mut().fail_all("the CPU worker was stopped");
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
    post(answer);
    if start {
        wasm_bindgen_futures::spawn_local(make_tasks());
    }
}

/// Makes the queued tasks a piece at a time, resting as each asks, and at least yielding
/// between pieces: other requests (a coarse stand-in, a stroke) are answered meanwhile.
/// A queue an earlier request left borrowed (it threw inside the module) ends the loop: the
/// worker script has reported that failure, and the module is not entered again.
async fn make_tasks() {
    while let Some((answer, rest_ms)) = QUEUE.with(|q| q.try_borrow_mut().ok().and_then(|mut q| q.next_piece())) {
        post(answer);
        gloo_timers::future::TimeoutFuture::new(rest_ms.round() as u32).await;
    }
}

/// Posts an answer, if any, to the page (its buffer transferred).
fn post(a: Option<Answer>) {
    let Some(a) = a else { return };
    let bytes = Uint8Array::from(a.encode().as_slice());
    let scope: web_sys::DedicatedWorkerGlobalScope = js_sys::global().unchecked_into();
    let _ = scope.post_message_with_transfer(&bytes, &Array::of1(&bytes.buffer()));
}
