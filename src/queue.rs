//! Work in flight under a budget, tagged with the epoch of the world it was made for: the one
//! bookkeeping of tiles, TEM batches, sketches, variants and blends.
//!
//! A job is pending (wanted, not yet started) → in flight → done, failed or cancelled. The
//! queue does not keep the pending list itself: every frame the world says what it wants,
//! nearest first, and [`JobQueue::start`] starts the first of those that are not in flight,
//! within a budget of jobs in flight. Every job carries the epoch of the world it was made
//! for; a new world starts a new epoch, and whatever comes back for an older one is dropped.
//! A leaf: the world's streams and the page's core use it; whoever runs the jobs is in
//! [`crate::jobs`].

use std::collections::HashMap;
use std::hash::Hash;

/// One unit of work: what to make, and for which world.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Job<K> {
    /// What to make (a tile coordinate, a quad key).
    pub key: K,
    /// The world epoch it was started in.
    pub epoch: u64,
}

/// What became of a finished job.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// The result belongs to the current world: keep it.
    Accepted,
    /// The world changed (or the job was cancelled) while it ran: drop the result.
    Stale,
}

/// Counters of a queue since it was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct JobStats {
    /// Jobs started.
    pub started: u64,
    /// Results accepted.
    pub done: u64,
    /// Jobs that failed.
    pub failed: u64,
    /// Results dropped because their world or request had gone.
    pub stale: u64,
    /// Jobs in flight now.
    pub in_flight: usize,
}

/// The jobs of one kind in flight, under a budget.
#[derive(Debug)]
pub struct JobQueue<K> {
    epoch: u64,
    in_flight: HashMap<K, u64>,
    budget: usize,
    stats: JobStats,
}

impl<K: Copy + Eq + Hash> JobQueue<K> {
    /// A queue that keeps at most `budget` jobs in flight (at least 1).
    pub fn new(budget: usize) -> Self {
        Self { epoch: 0, in_flight: HashMap::new(), budget: budget.max(1), stats: JobStats::default() }
    }

    /// A queue of world `epoch` that keeps at most `budget` jobs in flight (at least 1).
    pub fn at_epoch(budget: usize, epoch: u64) -> Self {
        Self { epoch, ..Self::new(budget) }
    }

    /// The current world epoch.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// A new world whose epoch is at least `epoch` (a later world of the same runners must
    /// never reuse an earlier one's epochs); returns the new epoch.
    pub fn new_epoch_from(&mut self, epoch: u64) -> u64 {
        self.epoch = self.epoch.max(epoch.saturating_sub(1));
        self.new_epoch()
    }

    /// A new world: every job in flight becomes stale; returns the new epoch.
    pub fn new_epoch(&mut self) -> u64 {
        self.epoch += 1;
        self.in_flight.clear();
        self.stats.in_flight = 0;
        self.epoch
    }

    /// Whether `key` is in flight for the current world.
    pub fn is_in_flight(&self, key: &K) -> bool {
        self.in_flight.contains_key(key)
    }

    /// Starts jobs for the first keys of `wanted` (in priority order) that are not in flight,
    /// until the budget is used up, and returns them.
    pub fn start(&mut self, wanted: impl IntoIterator<Item = K>) -> Vec<Job<K>> {
        let mut out = Vec::new();
        for key in wanted {
            if self.in_flight.len() >= self.budget {
                break;
            }
            if self.in_flight.contains_key(&key) {
                continue;
            }
            self.in_flight.insert(key, self.epoch);
            out.push(Job { key, epoch: self.epoch });
        }
        self.stats.started += out.len() as u64;
        self.stats.in_flight = self.in_flight.len();
        out
    }

    /// A job came back with its result: [`Outcome::Accepted`] if it is still wanted for the
    /// current world.
    pub fn finish(&mut self, job: &Job<K>) -> Outcome {
        let outcome = if job.epoch == self.epoch && self.in_flight.get(&job.key) == Some(&job.epoch) {
            self.in_flight.remove(&job.key);
            self.stats.done += 1;
            Outcome::Accepted
        } else {
            self.stats.stale += 1;
            Outcome::Stale
        };
        self.stats.in_flight = self.in_flight.len();
        outcome
    }

    /// A job failed: it leaves the flight (the world may ask for it again).
    pub fn fail(&mut self, job: &Job<K>) {
        if job.epoch == self.epoch && self.in_flight.get(&job.key) == Some(&job.epoch) {
            self.in_flight.remove(&job.key);
        }
        self.stats.failed += 1;
        self.stats.in_flight = self.in_flight.len();
    }

    /// Cancels the jobs in flight whose key `keep` rejects (their results will be stale).
    pub fn cancel_unless(&mut self, mut keep: impl FnMut(&K) -> bool) {
        self.in_flight.retain(|k, _| keep(k));
        self.stats.in_flight = self.in_flight.len();
    }

    /// Counters.
    pub fn stats(&self) -> JobStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The budget bounds the jobs in flight; keys in flight are not started twice; the next
    /// call starts the next wanted keys once results came back.
    #[test]
    fn start_respects_the_budget_and_skips_keys_in_flight() {
        let mut q = JobQueue::new(3);
        let a = q.start(0..10);
        assert_eq!(a.iter().map(|j| j.key).collect::<Vec<_>>(), vec![0, 1, 2]);
        assert!(q.start(0..10).is_empty(), "budget used up");
        assert_eq!(q.finish(&a[1]), Outcome::Accepted);
        assert_eq!(q.start([0, 1, 2, 3]).iter().map(|j| j.key).collect::<Vec<_>>(), vec![1], "1 is wanted again and free");
        assert_eq!(q.stats(), JobStats { started: 4, done: 1, failed: 0, stale: 0, in_flight: 3 });
    }

    /// Results of an older epoch, of cancelled jobs and duplicates are stale; a failed job can
    /// start again.
    #[test]
    fn stale_results_are_dropped() {
        let mut q = JobQueue::new(8);
        let old = q.start([7, 8, 9]);
        assert_eq!(q.new_epoch(), 1);
        assert_eq!(q.finish(&old[0]), Outcome::Stale, "made for the previous world");
        let new = q.start([7, 8, 9]);
        assert!(new.iter().all(|j| j.epoch == 1));
        q.cancel_unless(|k| *k != 8);
        assert_eq!(q.finish(&new[1]), Outcome::Stale, "cancelled");
        assert_eq!(q.finish(&new[0]), Outcome::Accepted);
        assert_eq!(q.finish(&new[0]), Outcome::Stale, "already finished");
        q.fail(&new[2]);
        assert_eq!(q.start([9]).len(), 1, "a failed job may start again");
        assert_eq!(q.stats(), JobStats { started: 7, done: 1, failed: 1, stale: 3, in_flight: 1 });
    }
}
