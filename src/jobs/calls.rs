//! The calls a transport to a runner on another thread (the page's Web Worker) waits on: each
//! request's reply by id, as a future, and why the other side is gone once it is. The
//! transport only posts bytes and hands back what arrives.

use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;
use std::task::{Poll, Waker};

use super::protocol::Answer;

/// One call's reply (encoded answer bytes, or why none will come) and who waits for it.
#[derive(Default)]
struct Slot {
    reply: Option<Result<Vec<u8>, String>>,
    waker: Option<Waker>,
}

/// The calls waiting for their replies.
#[derive(Default)]
pub struct Calls {
    waiting: HashMap<u32, Rc<RefCell<Slot>>>,
    gone: Option<String>,
}

impl Calls {
    /// Why the other side is gone, if it is.
    pub fn gone(&self) -> Option<String> {
        self.gone.clone()
    }

    /// Waits for the reply to request `id`: its bytes, or why none will come (the other side
    /// was gone already, or goes before it answers).
    pub fn wait(&mut self, id: u32) -> impl Future<Output = Result<Vec<u8>, String>> + use<> {
        let slot = Rc::new(RefCell::new(Slot { reply: self.gone.clone().map(Err), waker: None }));
        if self.gone.is_none() {
            self.waiting.insert(id, slot.clone());
        }
        std::future::poll_fn(move |cx| {
            let mut s = slot.borrow_mut();
            match s.reply.take() {
                Some(r) => Poll::Ready(r),
                None => {
                    s.waker = Some(cx.waker().clone());
                    Poll::Pending
                }
            }
        })
    }

    /// Request `id` will have no reply (it could not be posted): why.
    pub fn drop_call(&mut self, id: u32, why: String) {
        if let Some(slot) = self.waiting.remove(&id) {
            Self::settle(&slot, Err(why));
        }
    }

    /// A reply arrived (an encoded [`Answer`]): it settles the call of its id, if one waits.
    pub fn reply(&mut self, bytes: Vec<u8>) {
        let id = Answer::peek_id(&bytes[..bytes.len().min(8)]).unwrap_or(0);
        if let Some(slot) = self.waiting.remove(&id) {
            Self::settle(&slot, Ok(bytes));
        }
    }

    /// The other side is gone (the first reason is kept): every waiting call fails with it.
    pub fn fail_all(&mut self, why: &str) {
        let why = self.gone.get_or_insert_with(|| why.to_string()).clone();
        for (_, slot) in self.waiting.drain() {
            Self::settle(&slot, Err(why.clone()));
        }
    }

    fn settle(slot: &RefCell<Slot>, reply: Result<Vec<u8>, String>) {
        let mut s = slot.borrow_mut();
        s.reply = Some(reply);
        if let Some(w) = s.waker.take() {
            w.wake();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::jobs::protocol::Reply;

    fn poll<F: Future>(f: std::pin::Pin<&mut F>) -> Poll<F::Output> {
        f.poll(&mut std::task::Context::from_waker(Waker::noop()))
    }

    /// Replies settle the calls of their ids in any order; a reply nobody waits for is
    /// dropped; once the other side is gone, waiting calls and later ones fail with the first
    /// reason given.
    #[test]
    fn replies_settle_their_calls_and_a_gone_side_fails_the_rest() {
        let mut calls = Calls::default();
        let mut a = std::pin::pin!(calls.wait(7));
        let mut b = std::pin::pin!(calls.wait(8));
        let mut c = std::pin::pin!(calls.wait(9));
        assert!(poll(a.as_mut()).is_pending());
        calls.reply(Answer { id: 8, reply: Reply::Stale }.encode());
        calls.reply(Answer { id: 99, reply: Reply::Stale }.encode());
        let Poll::Ready(Ok(bytes)) = poll(b.as_mut()) else { panic!("8 answered") };
        assert_eq!(Answer::decode(&bytes).unwrap().id, 8);
        assert!(poll(a.as_mut()).is_pending());
        calls.drop_call(9, "could not post".into());
        assert_eq!(poll(c.as_mut()), Poll::Ready(Err("could not post".into())));
        calls.fail_all("it trapped");
        calls.fail_all("later");
        assert_eq!(poll(a.as_mut()), Poll::Ready(Err("it trapped".into())));
        let mut d = std::pin::pin!(calls.wait(10));
        assert_eq!(poll(d.as_mut()), Poll::Ready(Err("it trapped".into())));
        assert_eq!(calls.gone().as_deref(), Some("it trapped"));
    }
}
