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
//!
//! On a software adapter a view that has not changed is not drawn again ([`SceneKey`]): the
//! rasteriser runs on the cores that make the world's tiles, and redrawing the same picture
//! (only the water's ripples move) took one of them. The page then wakes every
//! [`STILL_FRAME_MS`] to take what came back and to see whether anything changed.

use std::sync::Arc;

use crate::render::FrameParams;
use crate::world::quadtree::{NodeData, NodeId};

/// How long (milliseconds) a page on a software adapter waits before its next frame when the
/// last one found the view unchanged and drew nothing: 20 frames a second of the page's own
/// work (what came back, the camera, the overlay) without the 3-D view's rasterising.
pub const STILL_FRAME_MS: u64 = 50;

/// What a frame of the 3-D view shows: each node (which one and its content version) and the
/// frame's parameters but for the water's clock. Two frames with equal keys draw the same
/// terrain from the same camera in the same light.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneKey {
    nodes: Vec<(NodeId, u64)>,
    params: FrameParams,
}

impl SceneKey {
    /// The key of a frame drawing `nodes` with `params`.
    pub fn of(nodes: &[Arc<NodeData>], params: &FrameParams) -> Self {
        let nodes = nodes.iter().map(|n| (n.id, n.version)).collect();
        Self { nodes, params: FrameParams { time_s: 0.0, ..*params } }
    }
}

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

    /// A frame was not drawn (its view was unchanged): the next frame drawn reports no
    /// interval, since the time between them is not a frame's time.
    pub fn skipped(&mut self) {
        self.last_drawn_ms = None;
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

    /// Frame 2 after a frame skipped as unchanged reports no interval; frame 3, drawn right
    /// after it, reports its 40 ms.
    #[test]
    fn a_skipped_frame_leaves_the_next_frame_without_an_interval() {
        let mut p = FramePacer::default();
        p.drawn(0.0);
        p.gpu_done(1);
        p.skipped();
        assert_eq!(p.drawn(900.0), (2, None));
        p.gpu_done(2);
        assert_eq!(p.drawn(940.0), (3, Some(40.0)));
    }

    /// The water's clock alone leaves the key equal; a node's new content version, one node
    /// fewer, or the camera 1 m east each make it differ.
    #[test]
    fn a_scene_key_changes_with_nodes_and_camera_but_not_with_the_waters_clock() {
        use crate::world::quadtree::NodeData;
        let tile = crate::grid::TileCoord { i: 0, j: 0 };
        let node =
            |depth: u8, version: u64| Arc::new(NodeData { id: NodeId { tile, depth, x: 0, y: 0 }, heights: vec![], min_m: 0.0, max_m: 1.0, skirt_m: 1.0, version, stride: 1 });
        let nodes = vec![node(0, 7), node(1, 8)];
        let params = FrameParams {
            camera: crate::render::Camera::default(),
            size: [480, 300],
            sun_dir: glam::Vec3::Y,
            fog_start_m: 1000.0,
            fog_end_m: 9000.0,
            water_level_m: 0.0,
            amplitude_m: 2000.0,
            show_lod: false,
            time_s: 1.0,
            plain_shading: false,
        };
        let key = SceneKey::of(&nodes, &params);
        assert_eq!(SceneKey::of(&nodes, &FrameParams { time_s: 99.5, ..params }), key);
        assert_ne!(SceneKey::of(&[node(0, 7), node(1, 9)], &params), key);
        assert_ne!(SceneKey::of(&nodes[..1], &params), key);
        let mut moved = params;
        moved.camera.position_m.x += 1.0;
        assert_ne!(SceneKey::of(&nodes, &moved), key);
    }

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
