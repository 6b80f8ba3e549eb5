// The CPU worker's script (started from a blob by src/web/worker.rs). The first message carries
// the URL of the page's wasm-bindgen glue and the compiled module; later messages are
// {id, bytes} requests, answered by the module's terrain_worker_message. A trap is reported to
// the page as {id, trap}, so it sees a dead worker instead of a reply that never comes.
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
