//! The CPU runner on a native thread: the same [`Runner`] and the same bytes as the page's
//! Web Worker, so the CLI, the tests and the page run one code path.

use std::sync::mpsc::{Receiver, Sender, channel};
use std::thread::JoinHandle;

use super::protocol::{Answer, Envelope, Malformed};
use super::runner::Runner;

/// A [`Runner`] on its own thread, fed encoded requests and answering encoded replies in order.
pub struct NativeRunner {
    to: Option<Sender<Vec<u8>>>,
    from: Receiver<Vec<u8>>,
    thread: Option<JoinHandle<()>>,
}

impl NativeRunner {
    /// Starts the thread; its kernels use `threads` threads.
    pub fn spawn(threads: usize) -> Self {
        let (to, inbox) = channel::<Vec<u8>>();
        let (outbox, from) = channel();
        let thread = std::thread::spawn(move || {
            let mut runner = Runner::new(threads);
            for bytes in inbox {
                let accepted = runner.accept_bytes(&bytes);
                let answer = runner.finish(accepted);
                if outbox.send(answer.encode()).is_err() {
                    break;
                }
            }
        });
        Self { to: Some(to), from, thread: Some(thread) }
    }

    /// Posts encoded request bytes.
    pub fn post(&self, bytes: Vec<u8>) {
        if let Some(to) = &self.to {
            let _ = to.send(bytes);
        }
    }

    /// Posts `env` and waits for its answer (the replies come back in order).
    pub fn call(&self, env: &Envelope) -> Result<Answer, Malformed> {
        self.post(env.encode());
        self.recv()
    }

    /// The next answer (blocking).
    pub fn recv(&self) -> Result<Answer, Malformed> {
        let bytes = self.from.recv().unwrap_or_default();
        Answer::decode(&bytes)
    }
}

impl Drop for NativeRunner {
    fn drop(&mut self) {
        self.to.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
