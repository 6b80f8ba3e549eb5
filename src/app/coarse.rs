//! Coarse first: while a learned tile and its neighbours are being made (hundreds of
//! milliseconds each in the page), the view draws the tile's 128 m network tile, which takes
//! tens. The stand-ins come from the worker like tiles do ([`TerrainApp::coarse_jobs`]), live
//! in the world ([`crate::world::stream::WorldStream`]) until their tile can be drawn, and are
//! drawn as root nodes ([`NodeData::from_coarse`]).

use std::collections::HashMap;
use std::sync::Arc;

use super::{LearnedStatus, SourceKind, TerrainApp};
use crate::grid::TileCoord;
use crate::queue::Job;
use crate::world::quadtree::{LodView, NodeData};
use crate::world::stream::WorldStream;

/// Root nodes built from stand-ins, with the count of the 3×3 tiles around whose data they
/// were built from (rebuilt when it changes: the edges then meet a neighbour).
#[derive(Default)]
pub struct CoarseNodes {
    built: HashMap<TileCoord, (usize, Arc<NodeData>)>,
}

impl CoarseNodes {
    /// The stand-in nodes to draw for `view` around the tiles that cannot be drawn yet
    /// (`drawable` can), in the frustum, nearest first; nodes of tiles no longer standing in
    /// are forgotten.
    pub fn select(&mut self, world: &WorldStream, drawable: &[TileCoord], view: &LodView) -> Vec<Arc<NodeData>> {
        let eye = view.eye_m;
        let stand_ins = world.coarse_stand_ins(eye.x, eye.z, drawable);
        self.built.retain(|c, _| stand_ins.iter().any(|(s, _)| s == c));
        let mut out = Vec::new();
        for (c, _) in stand_ins {
            let known = c.window3x3().iter().filter(|n| world.coarse(**n).is_some() || world.contains(**n)).count();
            let fresh = self.built.get(&c).is_some_and(|(k, _)| *k == known);
            if !fresh {
                let Some(d) = NodeData::from_coarse(c, world) else { continue };
                self.built.insert(c, (known, Arc::new(d)));
            }
            let d = &self.built[&c].1;
            let (min, max) = d.bounds_m();
            if view.frustum.intersects_box((min - eye).as_vec3(), (max - eye).as_vec3()) {
                out.push(d.clone());
            }
        }
        out
    }

    /// Forgets every node (a new world).
    pub fn clear(&mut self) {
        self.built.clear();
    }
}

impl TerrainApp {
    /// Coarse stand-ins to ask the worker for ([`crate::jobs::protocol::Request::Coarse`]):
    /// the learned world's tiles near the eye that cannot be drawn yet, nearest first. Each
    /// must come back through [`coarse_done`](Self::coarse_done) or
    /// [`coarse_failed`](Self::coarse_failed).
    pub fn coarse_jobs(&mut self) -> Vec<Job<TileCoord>> {
        if self.source() != SourceKind::Learned || !matches!(self.learned, LearnedStatus::Ready { .. }) {
            return Vec::new();
        }
        let eye = self.camera.position_m;
        self.world.start_coarse_jobs(eye.x, eye.z)
    }

    /// A stand-in came back (128 m heights, metres): kept if it belongs to the world shown.
    pub fn coarse_done(&mut self, job: &Job<TileCoord>, heights: Vec<f32>) -> bool {
        self.world.finish_coarse(job, heights)
    }

    /// Adds the stand-ins to draw for `view` to `nodes` (`tiles`: the tiles drawn whole) and
    /// returns the tiles the view shows, whole or standing in.
    pub(super) fn add_coarse(&mut self, nodes: &mut Vec<Arc<NodeData>>, tiles: &[TileCoord], view: &LodView) -> Vec<TileCoord> {
        let coarse = self.coarse_nodes.select(&self.world, tiles, view);
        self.stats.coarse_drawn = coarse.len();
        let shown = tiles.iter().copied().chain(coarse.iter().map(|d| d.id.tile)).collect();
        nodes.extend(coarse);
        shown
    }

    /// A stand-in could not be made: it may be asked for again.
    pub fn coarse_failed(&mut self, job: &Job<TileCoord>) {
        self.world.fail_coarse(job);
    }
}
