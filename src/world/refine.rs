//! Learned refinement below the 32 m base spacing: the patches the TEM ladder makes (16, 8, 4,
//! 2, 1 m), where they sit in the world, which ones to make next, and the quadtree nodes they
//! feed.
//!
//! Geometry. The 32 m samples are cell centres: sample i covers x ∈ [32i − 16, 32i + 16) m. A
//! level-k pixel p (spacing s = 16 / 2^k m) covers [s·p − 16, s·(p + 1) − 16), so its parent is
//! pixel ⌊p / 2⌋ of the level above and the 32 m sample ⌊p / 2^(k+1)⌋ at the top. A patch
//! ([`PatchKey`]) is the core of 128 × 128 level-k pixels [128x, 128x + 128) × [128y, …) plus a
//! margin of [`PATCH_MARGIN`] pixels on every side. It is made from the quadrant of its parent
//! patch (or of the 32 m input at the first level) with the same margin around it.
//!
//! Seamlessness. The TEM's output pixel depends only on input pixels within its receptive
//! field ([`RECEPTIVE_OUT_PX`]), which the margin contains, so every stored pixel is a pure
//! function of its global position: two patches agree wherever they overlap, whatever order
//! they were made in. Node vertices sit on cell corners, each the mean of the four pixels
//! around it, so the shared edge of two neighbouring refined nodes is the same row of numbers.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use super::pins::{Pins, SoftEdge, detail_centre_m, detail_side};
use super::stream::WorldStream;
use crate::grid::coord::TileCoord;
use crate::models::tem::{LEVEL_SPACING_M, LEVELS, PATCH, QUAD, RECEPTIVE_OUT_PX};
use crate::queue::{Job, JobQueue, Outcome};

/// Margin (pixels) kept around a stored patch's core and read around a quadrant. It must
/// cover the receptive field, and node vertices (cell corners, apron included) of every node a
/// patch serves must fall inside it.
pub const PATCH_MARGIN: usize = 18;
/// Side of a model input window (pixels).
pub const INPUT_SIDE: usize = QUAD + 2 * PATCH_MARGIN;
/// Side of a stored patch (pixels).
pub const STORED_SIDE: usize = PATCH + 2 * PATCH_MARGIN;

const _: () = assert!(PATCH_MARGIN >= RECEPTIVE_OUT_PX);

/// Identity of a refined patch: its level (0 = 16 m) and core position (units of 128 pixels
/// of that level).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PatchKey {
    /// Level of the ladder (0 = 32 → 16 m, 4 = 2 → 1 m).
    pub level: u8,
    /// Core column (the core starts at level pixel 128·x).
    pub x: i64,
    /// Core row (the core starts at level pixel 128·y).
    pub y: i64,
}

impl PatchKey {
    /// Spacing of its pixels (metres).
    pub fn spacing_m(self) -> f64 {
        LEVEL_SPACING_M[self.level as usize]
    }

    /// The patch one level up whose quadrant this one refines.
    pub fn parent(self) -> PatchKey {
        PatchKey { level: self.level - 1, x: self.x.div_euclid(2), y: self.y.div_euclid(2) }
    }

    /// Which quadrant of its parent it refines: (column, row), each 0 or 1.
    pub fn quadrant(self) -> (usize, usize) {
        (self.x.rem_euclid(2) as usize, self.y.rem_euclid(2) as usize)
    }

    /// The tile it belongs to (patches leave the cache with it).
    pub fn tile(self) -> TileCoord {
        let per_tile = 2i64 << self.level;
        TileCoord::new(self.x.div_euclid(per_tile) as i32, self.y.div_euclid(per_tile) as i32)
    }

    /// World position (x, z) in metres of the centre of its core.
    pub fn centre_m(self) -> (f64, f64) {
        let s = self.spacing_m();
        let c = |v: i64| (v as f64 + 0.5) * PATCH as f64 * s - 16.0;
        (c(self.x), c(self.y))
    }
}

/// Where the first refined level reads its input: heights (metres) of the grid one level
/// coarser than it (the 32 m samples for level 0), in that grid's global pixel indices.
pub trait RefineInput {
    /// The `side` × `side` window starting at pixel (x0, y0), row-major; `None` if any of it
    /// is not available yet.
    fn window(&self, x0: i64, y0: i64, side: usize) -> Option<Vec<f32>>;
}

impl RefineInput for WorldStream {
    fn window(&self, x0: i64, y0: i64, side: usize) -> Option<Vec<f32>> {
        let mut out = Vec::with_capacity(side * side);
        for y in y0..y0 + side as i64 {
            for x in x0..x0 + side as i64 {
                out.push(self.sample(x, y)?);
            }
        }
        Some(out)
    }
}

/// One model evaluation to run: a patch and its input window (INPUT_SIDE², metres), tagged
/// with the epoch of the store that asked for it.
#[derive(Clone, Debug)]
pub struct RefineJob {
    /// The patch it makes.
    pub key: PatchKey,
    /// Input heights (metres), INPUT_SIDE² row-major.
    pub input: Vec<f32>,
    /// The [`PatchStore::epoch`] it was made for: a result for another epoch (an older world)
    /// is dropped, never stored.
    pub epoch: u64,
}

/// Counters of the refinement.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct RefineStats {
    /// Patches (quads) made since creation.
    pub quads_made: u64,
    /// Model batches run.
    pub batches: u64,
    /// Time spent in inference (milliseconds, including read-back).
    pub inference_ms: f64,
    /// Patches cached now.
    pub cached: usize,
    /// Patches being computed now.
    pub in_flight: usize,
    /// Distinct patches asked for since the requests were last taken (at most one per node
    /// drawn: requests are renewed every frame, never accumulated).
    pub requests: usize,
    /// Results dropped because they belonged to an older world (epoch).
    pub stale_dropped: u64,
}

impl RefineStats {
    /// Mean inference time per quad (milliseconds).
    pub fn ms_per_quad(&self) -> f64 {
        if self.quads_made == 0 { 0.0 } else { self.inference_ms / self.quads_made as f64 }
    }
}

/// The refined patches of one world (one epoch), the requests of the current frame and the
/// jobs in flight.
pub struct PatchStore {
    first_level: usize,
    patches: HashMap<PatchKey, Arc<Vec<f32>>>,
    /// Patch → smallest priority asked for it since the requests were last taken.
    requests: HashMap<PatchKey, f64>,
    /// The jobs in flight, of the store's world epoch.
    jobs: JobQueue<PatchKey>,
    stats: RefineStats,
    /// Pinned terrain whose own detail replaces the TEM's output, and the tile whose
    /// north-west corner is pixel (0, 0) of every level ([`Self::with_pins`]).
    pins: Option<(Pins, TileCoord)>,
}

impl PatchStore {
    /// An empty store of world `epoch` whose first level reads a [`RefineInput`] (level 0
    /// reads the 32 m world; the CLI may start lower for finer input).
    pub fn new(first_level: usize, epoch: u64) -> Self {
        let jobs = JobQueue::at_epoch(usize::MAX, epoch);
        Self { first_level: first_level.min(LEVELS - 1), patches: HashMap::new(), requests: HashMap::new(), jobs, stats: RefineStats::default(), pins: None }
    }

    /// The store with pinned terrain: wherever a pinned tile keeps its own heights at a level
    /// ([`PinnedTile::detail`](crate::world::pins::PinnedTile::detail)), a stored patch of
    /// that level takes them instead of the TEM's output, margins included, so patches still
    /// agree wherever they overlap and the levels below refine the pin's own heights. `origin`
    /// is the tile whose north-west corner is pixel (0, 0) of every level: tile (0, 0) in the
    /// world, the region's first tile where a region is refined alone.
    pub fn with_pins(mut self, pins: Pins, origin: TileCoord) -> Self {
        self.pins = (pins.detail_samples() > 0).then_some((pins, origin));
        self
    }

    /// Writes the pins' own heights over the stored patch `key` (STORED_SIDE²) where they
    /// have that level.
    fn overlay_pins(&self, key: PatchKey, out: &mut [f32]) {
        let Some((pins, origin)) = &self.pins else { return };
        let level = key.level as usize;
        let per = detail_side(level) as i64;
        let (x0, y0) = (key.x * PATCH as i64 - PATCH_MARGIN as i64, key.y * PATCH as i64 - PATCH_MARGIN as i64);
        let (x1, y1) = (x0 + STORED_SIDE as i64, y0 + STORED_SIDE as i64);
        for tj in y0.div_euclid(per)..=(y1 - 1).div_euclid(per) {
            for ti in x0.div_euclid(per)..=(x1 - 1).div_euclid(per) {
                let Some(tile) = pins.get(origin.offset(ti as i32, tj as i32)) else { continue };
                let Some(d) = tile.detail(level) else { continue };
                let (ax, bx) = (x0.max(ti * per), x1.min((ti + 1) * per));
                for y in y0.max(tj * per)..y1.min((tj + 1) * per) {
                    let src = ((y - tj * per) * per + ax - ti * per) as usize;
                    let dst = ((y - y0) * STORED_SIDE as i64 + ax - x0) as usize;
                    let len = (bx - ax) as usize;
                    match &tile.soft {
                        None => out[dst..dst + len].copy_from_slice(&d[src..src + len]),
                        Some(soft) => {
                            // Pixels here are counted from the origin tile's north-west corner.
                            let world = |p: i64, o: i32| detail_centre_m(level, o as i64 * per + p);
                            let z = world(y, origin.j);
                            for k in 0..len {
                                let w = soft.weight(world(ax + k as i64, origin.i), z);
                                out[dst + k] = SoftEdge::mix(w, d[src + k], out[dst + k]);
                            }
                        }
                    }
                }
            }
        }
    }

    /// The world epoch its jobs are tagged with.
    pub fn epoch(&self) -> u64 {
        self.jobs.epoch()
    }

    /// Counters.
    pub fn stats(&self) -> RefineStats {
        RefineStats { cached: self.patches.len(), in_flight: self.jobs.stats().in_flight, requests: self.requests.len(), ..self.stats }
    }

    /// The stored patch `key` (STORED_SIDE² metres: the core at offset PATCH_MARGIN).
    pub fn get(&self, key: PatchKey) -> Option<&Arc<Vec<f32>>> {
        self.patches.get(&key)
    }

    /// Asks for `key` in the next jobs; smaller `priority` first (e.g. distance, metres). A
    /// patch asked for twice keeps its smaller priority.
    pub fn request(&mut self, key: PatchKey, priority: f64) {
        if !self.patches.contains_key(&key) {
            let p = self.requests.entry(key).or_insert(priority);
            *p = p.min(priority);
        }
    }

    /// Forgets the requests not yet taken: the caller is about to ask again for what it needs
    /// now (the quadtree does at the start of every selection), so requests never pile up
    /// while no jobs are taken.
    pub fn clear_requests(&mut self) {
        self.requests.clear();
    }

    /// Turns this round's requests into at most `max` jobs of one level: each request becomes
    /// its first missing ancestor (parents come first); requests whose input is not available
    /// yet wait. The jobs are marked in flight until [`complete`](Self::complete) or
    /// [`abandon`](Self::abandon). Clears the requests.
    pub fn next_jobs(&mut self, input: &dyn RefineInput, max: usize) -> Vec<RefineJob> {
        let mut reqs: Vec<(f64, PatchKey)> = self.requests.drain().map(|(k, p)| (p, k)).collect();
        reqs.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut seen = HashSet::new();
        let mut jobs: Vec<RefineJob> = Vec::new();
        for (_, mut key) in reqs {
            if jobs.len() >= max {
                break;
            }
            while key.level as usize > self.first_level && !self.patches.contains_key(&key.parent()) {
                key = key.parent();
            }
            if (key.level as usize) < self.first_level || self.patches.contains_key(&key) || self.jobs.is_in_flight(&key) || !seen.insert(key) {
                continue;
            }
            if jobs.first().is_some_and(|j| j.key.level != key.level) {
                continue;
            }
            if let Some(inp) = self.input_for(key, input) {
                jobs.push(RefineJob { key, input: inp, epoch: self.epoch() });
            }
        }
        self.jobs.start(jobs.iter().map(|j| j.key));
        jobs
    }

    /// Jobs for exactly `keys` (all of one level, each with its parent stored or at the first
    /// level), marked in flight; keys already stored, in flight or without input are skipped.
    /// Linear in `keys` (for whole-DEM refinement, where every patch of a level is wanted).
    pub fn jobs_for(&mut self, keys: &[PatchKey], input: &dyn RefineInput) -> Vec<RefineJob> {
        let mut jobs = Vec::with_capacity(keys.len());
        for &key in keys {
            if self.patches.contains_key(&key) || self.jobs.is_in_flight(&key) {
                continue;
            }
            if let Some(inp) = self.input_for(key, input) {
                self.jobs.start([key]);
                jobs.push(RefineJob { key, input: inp, epoch: self.epoch() });
            }
        }
        jobs
    }

    /// The input window of `key`: from the parent patch's quadrant, or from `input` at the
    /// first level.
    pub fn input_for(&self, key: PatchKey, input: &dyn RefineInput) -> Option<Vec<f32>> {
        let m = PATCH_MARGIN as i64;
        if key.level as usize == self.first_level {
            return input.window(key.x * QUAD as i64 - m, key.y * QUAD as i64 - m, INPUT_SIDE);
        }
        let parent = self.patches.get(&key.parent())?;
        let (qx, qy) = key.quadrant();
        let (x0, y0) = (qx * QUAD, qy * QUAD);
        let mut out = Vec::with_capacity(INPUT_SIDE * INPUT_SIDE);
        for y in y0..y0 + INPUT_SIDE {
            out.extend_from_slice(&parent[y * STORED_SIDE + x0..y * STORED_SIDE + x0 + INPUT_SIDE]);
        }
        Some(out)
    }

    /// Stores the results of a batch made for world `epoch`: `raw` is the models' output for
    /// `keys` in order ((2·INPUT_SIDE)² metres each; a patch keeps its core and margin), `ms`
    /// the batch's time. This is the one way results come back, whoever made them. A batch of
    /// an older world is dropped whole (`Ok(0)`); a batch of the wrong size, or with a height
    /// that is not finite, is dropped whole (its patches may be asked for again) and the error
    /// says so; patches of tiles that `keep` rejects (they left meanwhile) are forgotten.
    /// Returns how many patches were stored.
    pub fn complete_batch(&mut self, epoch: u64, keys: &[PatchKey], raw: &[f32], ms: f64, keep: impl Fn(TileCoord) -> bool) -> Result<usize, String> {
        let per = (2 * INPUT_SIDE).pow(2);
        if epoch != self.epoch() {
            self.stats.stale_dropped += keys.len() as u64;
            return Ok(0);
        }
        if raw.len() != per * keys.len() {
            self.abandon(keys);
            return Err(format!("the TEM returned {} heights for {} patches of {per}", raw.len(), keys.len()));
        }
        let bad = raw.iter().filter(|h| !h.is_finite()).count();
        if bad > 0 {
            // Not one patch of the batch is kept: a model that makes NaN or infinity somewhere
            // is not trusted anywhere in the batch.
            self.abandon(keys);
            return Err(format!("the TEM returned {bad} heights that are not finite numbers; the batch was dropped"));
        }
        self.stats.batches += 1;
        let mut stored = 0;
        for (&key, raw) in keys.iter().zip(raw.chunks_exact(per)) {
            let job = Job { key, epoch };
            if !keep(key.tile()) {
                self.jobs.fail(&job);
                continue;
            }
            if self.jobs.finish(&job) == Outcome::Stale {
                self.stats.stale_dropped += 1;
                continue;
            }
            let (side, o) = (2 * INPUT_SIDE, PATCH_MARGIN);
            let mut out = Vec::with_capacity(STORED_SIDE * STORED_SIDE);
            for y in o..o + STORED_SIDE {
                out.extend_from_slice(&raw[y * side + o..y * side + o + STORED_SIDE]);
            }
            self.overlay_pins(key, &mut out);
            self.patches.insert(key, Arc::new(out));
            self.stats.quads_made += 1;
            self.stats.inference_ms += ms / keys.len() as f64;
            stored += 1;
        }
        Ok(stored)
    }

    /// Forgets jobs that failed, so they can be asked for again.
    pub fn abandon(&mut self, keys: &[PatchKey]) {
        let epoch = self.epoch();
        for &key in keys {
            self.jobs.fail(&Job { key, epoch });
        }
    }

    /// Drops the patches of tiles not in `keep`.
    pub fn retain_tiles(&mut self, keep: impl Fn(TileCoord) -> bool) {
        self.patches.retain(|k, _| keep(k.tile()));
    }

    /// Drops every patch of `level`.
    pub fn drop_level(&mut self, level: usize) {
        self.patches.retain(|k, _| k.level as usize != level);
    }

    /// The refined heights of `level` around (x, z) metres as one heightfield, what the page
    /// exports at that spacing: the largest square of k × k stored patches (k = 3, 2, 1) that
    /// holds the patch under (x, z), or the stored patch of that level nearest to it when that
    /// one is not made; their 128² core pixels, placed in the world's metric frame like
    /// [`super::export::from_tiles`]. `None` when no patch of `level` is stored.
    pub fn export_around(&self, level: usize, x_m: f64, z_m: f64) -> Option<crate::dem::Heightfield> {
        let s = LEVEL_SPACING_M[level];
        let span = PATCH as f64 * s;
        let under = |v: f64| ((v + 16.0) / span).floor() as i64;
        let (ux, uy) = (under(x_m), under(z_m));
        let here = |x: i64, y: i64| self.patches.contains_key(&PatchKey { level: level as u8, x, y });
        let (cx, cy) = if here(ux, uy) {
            (ux, uy)
        } else {
            let d = |k: &PatchKey| (k.x - ux).pow(2) + (k.y - uy).pow(2);
            let k = self.patches.keys().filter(|k| k.level as usize == level).min_by_key(|k| (d(k), k.y, k.x))?;
            (k.x, k.y)
        };
        // Squares holding (cx, cy): 3 × 3 centred on it, then each 2 × 2, then itself.
        let squares = [(3, cx - 1, cy - 1), (2, cx - 1, cy - 1), (2, cx, cy - 1), (2, cx - 1, cy), (2, cx, cy), (1, cx, cy)];
        let (k, x0, y0) = squares.into_iter().find(|&(k, x0, y0)| (0..k).all(|j| (0..k).all(|i| here(x0 + i, y0 + j))))?;
        let side = k as usize * PATCH;
        let mut data = vec![0f32; side * side];
        for j in 0..k {
            for i in 0..k {
                let patch = &self.patches[&PatchKey { level: level as u8, x: x0 + i, y: y0 + j }];
                for v in 0..PATCH {
                    let row = (j as usize * PATCH + v) * side + i as usize * PATCH;
                    let src = (v + PATCH_MARGIN) * STORED_SIDE + PATCH_MARGIN;
                    data[row..row + PATCH].copy_from_slice(&patch[src..src + PATCH]);
                }
            }
        }
        // Level pixel p covers [s·p − 16, s·(p + 1) − 16) m (x east, z south; y north).
        let corner = [x0 as f64 * span - 16.0, -(y0 as f64 * span - 16.0)];
        Some(crate::dem::Heightfield::new(side, side, s, data).with_geo(Some(crate::dem::GeoRef { origin_m: corner, epsg: None })))
    }

    /// Height (metres) of level pixel (px, py) of `level`, if its patch is stored (core pixels
    /// only).
    pub fn pixel(&self, level: usize, px: i64, py: i64) -> Option<f32> {
        let p = PATCH as i64;
        let key = PatchKey { level: level as u8, x: px.div_euclid(p), y: py.div_euclid(p) };
        let patch = self.patches.get(&key)?;
        let (u, v) = (px.rem_euclid(p) as usize + PATCH_MARGIN, py.rem_euclid(p) as usize + PATCH_MARGIN);
        Some(patch[v * STORED_SIDE + u])
    }
}

/// Runs `jobs` (one level) on `tem` now and stores the results in `store` through
/// [`PatchStore::complete_batch`] (blocking; native). Returns how many patches were made; on
/// an error the jobs are forgotten so they can be asked for again.
#[cfg(not(target_arch = "wasm32"))]
pub fn run_blocking(store: &mut PatchStore, tem: &crate::models::tem::TemSet, jobs: Vec<RefineJob>, keep: impl Fn(TileCoord) -> bool) -> Result<usize, String> {
    let Some(first) = jobs.first() else { return Ok(0) };
    let (level, epoch) = (first.key.level as usize, first.epoch);
    let keys: Vec<PatchKey> = jobs.iter().map(|j| j.key).collect();
    let t = web_time::Instant::now();
    match tem.enhance_blocking(level, jobs.into_iter().flat_map(|j| j.input).collect(), keys.len(), INPUT_SIDE) {
        Ok(raw) => store.complete_batch(epoch, &keys, &raw, t.elapsed().as_secs_f64() * 1e3, keep),
        Err(e) => {
            store.abandon(&keys);
            Err(e)
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::models::tem::{TemCpu, TemSet};
    use crate::world::TILE_SIZE_M;
    use crate::world::noise::ProceduralSource;

    pub(crate) fn world() -> WorldStream {
        let mut w = WorldStream::new(5, Box::new(ProceduralSource::default()), 1.0);
        w.update(TILE_SIZE_M * 0.5, TILE_SIZE_M * 0.5, 1e9);
        w
    }

    /// Models with random non-zero weights: if seams matched only because the output was
    /// plain bicubic, this would not show it.
    pub(crate) fn scrambled() -> TemSet {
        TemSet::from_cpu((0..5).map(|k| TemCpu::randomized(k, 0.05)).collect(), 1).unwrap()
    }

    pub(crate) fn run_all(store: &mut PatchStore, w: &WorldStream, tem: &TemSet) {
        loop {
            let jobs = store.next_jobs(w, 8);
            if jobs.is_empty() {
                break;
            }
            run_blocking(store, tem, jobs, |_| true).unwrap();
        }
    }

    #[test]
    fn keys_nest_and_belong_to_their_tile() {
        let k = PatchKey { level: 2, x: -9, y: 17 };
        assert_eq!(k.parent(), PatchKey { level: 1, x: -5, y: 8 });
        assert_eq!(k.quadrant(), (1, 1));
        assert_eq!(k.tile(), TileCoord::new(-2, 2), "8 level-2 patches per tile side");
    }
}
