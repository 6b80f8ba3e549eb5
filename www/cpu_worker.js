// The CPU worker's script (started from a blob by src/web/worker.rs). The first message carries
// the URL of the page's wasm-bindgen glue and the compiled module; later messages are
// {id, bytes} requests, answered by the module's terrain_worker_message. A trap is reported to
// the page as {id, trap}, so it sees a dead worker instead of a reply that never comes. After a
// trap the module is not entered again (its state may be half-changed: a queue left borrowed):
// every later request, one the page sent before it heard of the trap, gets the same report.
let ready = null;
let failed = null;
self.onmessage = (e) => {
  if (ready === null) {
    ready = import(e.data.glue).then(async (m) => { await m.default({ module_or_path: e.data.module }); return m; });
    ready.catch((err) => self.postMessage({ id: 0, trap: 'the CPU worker could not start: ' + err }));
    return;
  }
  const id = e.data.id;
  ready
    .then((m) => {
      if (failed !== null) throw failed;
      try {
        m.terrain_worker_message(e.data.bytes);
      } catch (err) {
        // At once: a request already queued behind this one must see it.
        failed = err;
        throw err;
      }
    })
    .catch((err) => self.postMessage({ id, trap: 'the CPU worker failed: ' + err }));
};
