//! Coarse first: while a learned tile and its neighbours are being made (hundreds of
//! milliseconds each in the page), the view draws the tile's 128 m network tile, which takes
//! tens. The stand-ins come from the worker like tiles do ([`TerrainApp::coarse_jobs`]), live
//! in the world ([`crate::world::stream::WorldStream`]) until their tile can be drawn, and are
//! drawn as root nodes ([`NodeData::from_coarse`]). The same 128 m tiles beyond the detailed
//! ones, out to [`crate::world::stream::FAR_FIELD_M`], are the far field: terrain to the
//! horizon, drawn with every 4th vertex.

use std::collections::HashMap;
use std::sync::Arc;

use super::{LearnedStatus, SourceKind, TerrainApp};
use crate::grid::TileCoord;
use crate::grid::coord::TILE_SIZE_M;
use crate::queue::Job;
use crate::world::quadtree::{LodView, NodeData};
use crate::world::stream::{FAR_FIELD_M, WorldStream};

/// Root nodes built from stand-ins and far-field tiles, with the count of the 3×3 tiles
/// around whose data they were built from (rebuilt when it changes: the edges then meet a
/// neighbour) and their stride.
#[derive(Default)]
pub struct CoarseNodes {
    built: HashMap<TileCoord, (usize, u8, Arc<NodeData>)>,
}

/// The far field's draw stride: every 4th vertex (512 m apart), beyond the detailed tiles.
const FAR_STRIDE: u8 = 4;

/// Far-field tiles of a world made on the main thread (procedural, sketch) made per frame
/// (each 32² samples of noise or of the sketch's surroundings).
pub const LOCAL_FAR_PER_FRAME: usize = 8;

impl CoarseNodes {
    /// The stand-in nodes to draw for `view` around the tiles that cannot be drawn yet
    /// (`drawable` can), in the frustum, nearest first; nodes of tiles no longer standing in
    /// are forgotten.
    ///
    /// Then the far field's that have arrived (`far_ring`: [`WorldStream::far_ring`] around
    /// the eye), drawn with every 4th vertex.
    pub fn select(&mut self, world: &WorldStream, drawable: &[TileCoord], far_ring: &[TileCoord], view: &LodView) -> Vec<Arc<NodeData>> {
        let eye = view.eye_m;
        let near = world.coarse_stand_ins(eye.x, eye.z, drawable).into_iter().map(|(c, _)| (c, 1));
        let far = world.far_stand_ins(far_ring).into_iter().map(|(c, _)| (c, FAR_STRIDE));
        let wanted: Vec<(TileCoord, u8)> = near.chain(far).collect();
        self.built.retain(|c, _| wanted.iter().any(|(w, _)| w == c));
        let mut out = Vec::new();
        for (c, stride) in wanted {
            let known = c.window3x3().iter().filter(|n| world.coarse(**n).is_some() || world.contains(**n)).count();
            let fresh = self.built.get(&c).is_some_and(|(k, s, _)| *k == known && *s == stride);
            if !fresh {
                let Some(d) = NodeData::from_coarse(c, world, stride) else { continue };
                self.built.insert(c, (known, stride, Arc::new(d)));
            }
            let d = &self.built[&c].2;
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
        if !self.learned_shown_ready() || self.sketch_unsettled() {
            return Vec::new();
        }
        let eye = self.camera.position_m;
        self.world.start_coarse_jobs(eye.x, eye.z)
    }

    /// A stand-in came back (128 m heights, metres): kept if it belongs to the world shown.
    pub fn coarse_done(&mut self, job: &Job<TileCoord>, heights: Vec<f32>) -> bool {
        self.world.finish_coarse(job, heights)
    }

    /// Adds the stand-ins to draw for `view` to `nodes` (`tiles`: the tiles drawn whole;
    /// `ring`: [`WorldStream::far_ring`] around the eye) and returns the tiles the view shows,
    /// whole or standing in.
    pub(super) fn add_coarse(&mut self, nodes: &mut Vec<Arc<NodeData>>, tiles: &[TileCoord], ring: &[TileCoord], view: &LodView) -> Vec<TileCoord> {
        let coarse = self.coarse_nodes.select(&self.world, tiles, ring, view);
        self.stats.far_drawn = coarse.iter().filter(|d| d.stride == FAR_STRIDE).count();
        self.stats.far_pending = ring.iter().filter(|c| self.world.coarse(**c).is_none()).count();
        self.stats.coarse_drawn = coarse.len() - self.stats.far_drawn;
        let shown = tiles.iter().copied().chain(coarse.iter().map(|d| d.id.tile)).collect();
        nodes.extend(coarse);
        shown
    }

    /// Makes up to [`LOCAL_FAR_PER_FRAME`] far-field tiles of `ring` ([`WorldStream::far_ring`]
    /// around the eye) for a world made on the main thread, by its own source (the sketch's,
    /// the procedural one's; the procedural world's noise directly where its tiles come from
    /// the worker), once every wanted tile is made.
    pub(super) fn make_local_far_field(&mut self, ring: &[TileCoord]) {
        if !self.local_far_field() {
            return;
        }
        let eye = self.camera.position_m;
        if !self.world.missing(eye.x, eye.z).is_empty() {
            return;
        }
        let (seed, noise, procedural) = (self.settings.seed, self.settings.noise, self.source() == SourceKind::Procedural);
        let todo: Vec<TileCoord> = ring.iter().copied().filter(|c| self.world.coarse(*c).is_none()).take(LOCAL_FAR_PER_FRAME).collect();
        for c in todo {
            let tile = self.world.far_tile_here(c).or_else(|| procedural.then(|| crate::world::noise::coarse_tile(seed, &noise, c)));
            if let Some(t) = tile {
                self.world.insert_coarse(c, t);
            }
        }
    }

    /// Whether the world shown makes its far field on the main thread: the procedural world,
    /// and the sketch's once its terrain is here.
    fn local_far_field(&self) -> bool {
        match self.source() {
            SourceKind::Procedural => true,
            SourceKind::Sketch => self.world.made_here(),
            SourceKind::Learned => false,
        }
    }

    /// How far the view reaches (metres; the far plane, where the fog is whole): the detailed
    /// tiles' radius, or for a world with a far field (learned, procedural, sketch) the far
    /// field plus the eye's height, so it is seen from high above too.
    pub(super) fn view_far_m(&self) -> f32 {
        let detailed = (self.settings.radius_tiles + 0.5) * TILE_SIZE_M;
        let far = self.learned_shown_ready() || self.local_far_field();
        (if far { detailed.max(FAR_FIELD_M + 0.5 * TILE_SIZE_M + self.camera.position_m.y.max(0.0)) } else { detailed }) as f32
    }

    /// Distance fog (metres from the eye): where it starts and where it is whole. With a far
    /// field it is whole at the far field's edge seen from the eye (the slant distance to a
    /// point [`FAR_FIELD_M`] away at sea level), so that edge never shows, not even from high
    /// above; it starts at 35 % of that, or nearer the edge when the eye is high (at 90 % of
    /// the eye's height) so the ground below stays clear. Without one, it spans 35–100 % of
    /// the far plane.
    pub(super) fn fog_m(&self) -> (f32, f32) {
        let far = self.camera.far_m as f64;
        if !(self.learned_shown_ready() || self.local_far_field()) {
            return ((0.35 * far) as f32, far as f32);
        }
        let h = self.camera.position_m.y.max(0.0);
        let end = FAR_FIELD_M.hypot(h).min(far);
        let start = (0.35 * end).max(0.9 * h).min(0.9 * end);
        (start as f32, end as f32)
    }

    /// Whether the world shown is made by the learned networks with their models ready: the
    /// learned world, or the sketch pinned into it.
    pub(super) fn learned_shown_ready(&self) -> bool {
        (self.source() == SourceKind::Learned && matches!(self.learned, LearnedStatus::Ready { .. })) || self.sketch_in_learned()
    }

    /// A stand-in could not be made: it may be asked for again.
    pub fn coarse_failed(&mut self, job: &Job<TileCoord>) {
        self.world.fail_coarse(job);
    }
}
