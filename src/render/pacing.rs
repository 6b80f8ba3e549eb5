//! Frame pacing: a new frame of the 3-D view is drawn only once the GPU has finished the
//! previous one, so at most one frame of GPU work is ever queued.
//!
//! Without it the browser lets a page queue a second frame behind a slow one; on a software
//! adapter (SwiftShader, ~100 ms per frame on 2 cores) that queue fills and drains unevenly
//! and frames arrive in pairs, one twice as late as the median and the next at once. With one
//! frame in flight each starts when the GPU is free: steady intervals, and the view drawn
//! from the newest camera instead of one a frame old. On a hardware GPU the previous frame is
//! long done when the next one is due, and nothing changes.
//!
//! The shell draws when [`FramePacer::may_draw`] says so, calls [`FramePacer::drawn`] after
//! submitting, and reports the GPU's "work done" for that frame with [`FramePacer::gpu_done`].

/// How long (milliseconds) the pacer waits for the GPU to report a frame done before it
/// draws the next one anyway: a device that never answers must not freeze the view.
pub const GPU_STALL_MS: f64 = 1000.0;

/// Whether a frame may be drawn now, and the intervals between frames drawn.
#[derive(Clone, Debug, Default)]
pub struct FramePacer {
    /// Frames drawn so far (the last one's number).
    drawn: u64,
    /// The frame whose GPU work is awaited: its number and when it was submitted (ms).
    waiting: Option<(u64, f64)>,
    /// When the previous frame was drawn (ms).
    last_drawn_ms: Option<f64>,
}

impl FramePacer {
    /// Whether a frame may be drawn at `now_ms`: the GPU has finished the previous one, or
    /// it has been waited for [`GPU_STALL_MS`] or longer.
    pub fn may_draw(&self, now_ms: f64) -> bool {
        self.waiting.is_none_or(|(_, since)| now_ms - since >= GPU_STALL_MS)
    }

    /// Whether the GPU work of a drawn frame is still awaited.
    pub fn waiting(&self) -> bool {
        self.waiting.is_some()
    }

    /// Records a frame submitted at `now_ms`. Returns its number (to pass to
    /// [`FramePacer::gpu_done`] when the GPU has finished it) and the interval (ms) since the
    /// previous frame drawn, if there was one.
    pub fn drawn(&mut self, now_ms: f64) -> (u64, Option<f64>) {
        self.drawn += 1;
        self.waiting = Some((self.drawn, now_ms));
        let interval = self.last_drawn_ms.map(|t| now_ms - t);
        self.last_drawn_ms = Some(now_ms);
        (self.drawn, interval)
    }

    /// The GPU has finished frame `frame` and everything submitted before it. A report about
    /// an older frame than the one awaited changes nothing.
    pub fn gpu_done(&mut self, frame: u64) {
        if self.waiting.is_some_and(|(n, _)| frame >= n) {
            self.waiting = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first frame may be drawn; after it, none until the GPU reports frame 1 done.
    #[test]
    fn a_second_frame_waits_for_the_first_frames_gpu_work() {
        let mut p = FramePacer::default();
        assert!(p.may_draw(0.0));
        assert_eq!(p.drawn(0.0), (1, None));
        assert!(p.waiting());
        assert!(!p.may_draw(16.7));
        assert!(!p.may_draw(900.0));
        p.gpu_done(1);
        assert!(!p.waiting());
        assert!(p.may_draw(120.0));
        assert_eq!(p.drawn(133.3), (2, Some(133.3)));
    }

    /// A late report about frame 1 does not release frame 2; frame 2's (or a later one's) does.
    #[test]
    fn a_report_about_an_older_frame_does_not_release_the_newer_one() {
        let mut p = FramePacer::default();
        p.drawn(0.0);
        p.gpu_done(1);
        p.drawn(100.0);
        p.gpu_done(1);
        assert!(!p.may_draw(150.0));
        p.gpu_done(3);
        assert!(p.may_draw(150.0));
    }

    /// With no report, the next frame is drawn 1,000 ms after the last one was submitted,
    /// not 1 ms sooner.
    #[test]
    fn a_gpu_that_never_reports_delays_the_next_frame_by_the_stall_time_only() {
        let mut p = FramePacer::default();
        p.drawn(500.0);
        assert!(!p.may_draw(500.0 + GPU_STALL_MS - 1.0));
        assert!(p.may_draw(500.0 + GPU_STALL_MS));
        assert_eq!(p.drawn(500.0 + GPU_STALL_MS), (2, Some(GPU_STALL_MS)));
    }
}
