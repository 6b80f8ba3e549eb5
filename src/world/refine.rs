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

use super::coord::TileCoord;
use super::quadtree::{BASE_DATA_DEPTH, NODE_APRON_GRID, NODE_QUADS, NodeData, NodeId};
use super::stream::WorldStream;
use crate::models::tem::{LEVEL_SPACING_M, LEVELS, PATCH, QUAD, RECEPTIVE_OUT_PX};

/// Margin (pixels) kept around a stored patch's core and read around a quadrant. It must
/// cover the receptive field, and node vertices (cell corners, apron included) of every node a
/// patch serves must fall inside it.
pub const PATCH_MARGIN: usize = 18;
/// Side of a model input window (pixels).
pub const INPUT_SIDE: usize = QUAD + 2 * PATCH_MARGIN;
/// Side of a stored patch (pixels).
pub const STORED_SIDE: usize = PATCH + 2 * PATCH_MARGIN;

const _: () = assert!(PATCH_MARGIN >= RECEPTIVE_OUT_PX);

/// Level-k nodes are this much deeper than the level: a depth-(k + 3) node has the vertex
/// spacing of level k (16 m at depth 3 … 1 m at depth 7).
pub const DEPTH_OF_LEVEL_0: u8 = BASE_DATA_DEPTH + 1;

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

    /// The patch whose data a refined node uses, and the level: `None` above the refined
    /// depths or below the last level.
    pub fn for_node(id: NodeId) -> Option<PatchKey> {
        let level = id.depth.checked_sub(DEPTH_OF_LEVEL_0)? as usize;
        if level >= LEVELS {
            return None;
        }
        let (gx, gz) = global_node(id);
        let per_patch = (PATCH / NODE_QUADS) as i64;
        Some(PatchKey { level: level as u8, x: gx.div_euclid(per_patch), y: gz.div_euclid(per_patch) })
    }
}

/// Global index (x, z) of a node among all nodes of its depth.
fn global_node(id: NodeId) -> (i64, i64) {
    let n = 1i64 << id.depth;
    (id.tile.i as i64 * n + id.x as i64, id.tile.j as i64 * n + id.y as i64)
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
    epoch: u64,
    patches: HashMap<PatchKey, Arc<Vec<f32>>>,
    /// Patch → smallest priority asked for it since the requests were last taken.
    requests: HashMap<PatchKey, f64>,
    in_flight: HashSet<PatchKey>,
    stats: RefineStats,
}

impl PatchStore {
    /// An empty store of world `epoch` whose first level reads a [`RefineInput`] (level 0
    /// reads the 32 m world; the CLI may start lower for finer input).
    pub fn new(first_level: usize, epoch: u64) -> Self {
        Self { first_level: first_level.min(LEVELS - 1), epoch, patches: HashMap::new(), requests: HashMap::new(), in_flight: HashSet::new(), stats: RefineStats::default() }
    }

    /// The world epoch its jobs are tagged with.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Counters.
    pub fn stats(&self) -> RefineStats {
        RefineStats { cached: self.patches.len(), in_flight: self.in_flight.len(), requests: self.requests.len(), ..self.stats }
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
            if (key.level as usize) < self.first_level || self.patches.contains_key(&key) || self.in_flight.contains(&key) || !seen.insert(key) {
                continue;
            }
            if jobs.first().is_some_and(|j| j.key.level != key.level) {
                continue;
            }
            if let Some(inp) = self.input_for(key, input) {
                jobs.push(RefineJob { key, input: inp, epoch: self.epoch });
            }
        }
        for j in &jobs {
            self.in_flight.insert(j.key);
        }
        jobs
    }

    /// Jobs for exactly `keys` (all of one level, each with its parent stored or at the first
    /// level), marked in flight; keys already stored, in flight or without input are skipped.
    /// Linear in `keys` (for whole-DEM refinement, where every patch of a level is wanted).
    pub fn jobs_for(&mut self, keys: &[PatchKey], input: &dyn RefineInput) -> Vec<RefineJob> {
        let mut jobs = Vec::with_capacity(keys.len());
        for &key in keys {
            if self.patches.contains_key(&key) || self.in_flight.contains(&key) {
                continue;
            }
            if let Some(inp) = self.input_for(key, input) {
                self.in_flight.insert(key);
                jobs.push(RefineJob { key, input: inp, epoch: self.epoch });
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

    /// Stores the result of a job made for `epoch`: `raw` is the model's (2·INPUT_SIDE)²
    /// output (metres); the patch keeps the core and margin. `ms` is this job's share of the
    /// batch time. Returns whether it was stored: a result of another epoch (a world that has
    /// since been replaced) or of the wrong size is dropped.
    pub fn complete(&mut self, epoch: u64, key: PatchKey, raw: &[f32], ms: f64) -> bool {
        let side = 2 * INPUT_SIDE;
        if epoch != self.epoch {
            self.stats.stale_dropped += 1;
            return false;
        }
        if raw.len() != side * side {
            self.in_flight.remove(&key);
            return false;
        }
        let o = PATCH_MARGIN;
        let mut out = Vec::with_capacity(STORED_SIDE * STORED_SIDE);
        for y in o..o + STORED_SIDE {
            out.extend_from_slice(&raw[y * side + o..y * side + o + STORED_SIDE]);
        }
        self.in_flight.remove(&key);
        self.patches.insert(key, Arc::new(out));
        self.stats.quads_made += 1;
        self.stats.inference_ms += ms;
        true
    }

    /// Counts one model batch.
    pub fn count_batch(&mut self) {
        self.stats.batches += 1;
    }

    /// Forgets jobs that failed, so they can be asked for again.
    pub fn abandon(&mut self, keys: &[PatchKey]) {
        for k in keys {
            self.in_flight.remove(k);
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

    /// Height (metres) of level pixel (px, py) of `level`, if its patch is stored (core pixels
    /// only).
    pub fn pixel(&self, level: usize, px: i64, py: i64) -> Option<f32> {
        let p = PATCH as i64;
        let key = PatchKey { level: level as u8, x: px.div_euclid(p), y: py.div_euclid(p) };
        let patch = self.patches.get(&key)?;
        let (u, v) = (px.rem_euclid(p) as usize + PATCH_MARGIN, py.rem_euclid(p) as usize + PATCH_MARGIN);
        Some(patch[v * STORED_SIDE + u])
    }

    /// Builds refined node `id` (depth 3 … 7) from its stored patch: every vertex the mean of
    /// the four pixels around its corner. `None` if the patch is not stored. Skirts hang 1 m +
    /// the node's height range + twice its largest edge departure from the 32 m surface below
    /// the edges, which covers the gap to any coarser neighbour (whose edge lies between the
    /// 32 m surface and its own refinement).
    pub fn node(&self, id: NodeId, world: &WorldStream) -> Option<NodeData> {
        let key = PatchKey::for_node(id)?;
        let patch = self.patches.get(&key)?;
        let (gx, gz) = global_node(id);
        let q = NODE_QUADS as i64;
        let o = 1i64 << key.level; // pixel offset of cell corners: 16 m / spacing
        let start = (key.x * PATCH as i64 - PATCH_MARGIN as i64, key.y * PATCH as i64 - PATCH_MARGIN as i64);
        let px = |v: i64, s: i64| (v + o - 1 - s) as usize;
        let mut heights = Vec::with_capacity(NODE_APRON_GRID * NODE_APRON_GRID);
        for r in -1..=q + 1 {
            let y = px(gz * q + r, start.1);
            for c in -1..=q + 1 {
                let x = px(gx * q + c, start.0);
                let a = &patch[y * STORED_SIDE + x..y * STORED_SIDE + x + 2];
                let b = &patch[(y + 1) * STORED_SIDE + x..(y + 1) * STORED_SIDE + x + 2];
                heights.push((a[0] + a[1] + b[0] + b[1]) * 0.25);
            }
        }
        let mut d = NodeData::new(id, heights, 0.0);
        let (x0, z0) = id.origin_m();
        let s = id.spacing_m();
        let mut dev = 0f32;
        for k in 0..=NODE_QUADS as i32 {
            for (c, r) in [(k, 0), (k, NODE_QUADS as i32), (0, k), (NODE_QUADS as i32, k)] {
                let base = world.height_at(x0 + c as f64 * s, z0 + r as f64 * s)?;
                dev = dev.max((d.at(c, r) - base).abs());
            }
        }
        d.skirt_m = 1.0 + (d.max_m - d.min_m) + 2.0 * dev;
        Some(d)
    }
}

/// Runs `jobs` (one level) on `tem` now and stores the results in `store` (blocking; native).
/// Returns how many patches were made; on an error the jobs are forgotten so they can be asked
/// for again.
#[cfg(not(target_arch = "wasm32"))]
pub fn run_blocking(store: &mut PatchStore, tem: &crate::models::tem::TemSet, jobs: Vec<RefineJob>) -> Result<usize, String> {
    let Some(first) = jobs.first() else { return Ok(0) };
    let (level, epoch) = (first.key.level as usize, first.epoch);
    let keys: Vec<PatchKey> = jobs.iter().map(|j| j.key).collect();
    let t = web_time::Instant::now();
    let raw = match tem.enhance_blocking(level, jobs.into_iter().flat_map(|j| j.input).collect(), keys.len(), INPUT_SIDE) {
        Ok(raw) => raw,
        Err(e) => {
            store.abandon(&keys);
            return Err(e);
        }
    };
    let ms = t.elapsed().as_secs_f64() * 1e3 / keys.len() as f64;
    let per = (2 * INPUT_SIDE).pow(2);
    store.count_batch();
    let mut made = 0;
    for (i, k) in keys.iter().enumerate() {
        made += store.complete(epoch, *k, &raw[i * per..(i + 1) * per], ms) as usize;
    }
    Ok(made)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::models::tem::{Exec, TemCpu, TemSet};
    use crate::world::TILE_SIZE_M;
    use crate::world::noise::ProceduralSource;

    fn world() -> WorldStream {
        let mut w = WorldStream::new(5, Box::new(ProceduralSource::default()), 1.0);
        w.update(TILE_SIZE_M * 0.5, TILE_SIZE_M * 0.5, 1e9);
        w
    }

    /// Models with random non-zero weights: if seams matched only because the output was
    /// plain bicubic, this would not show it.
    fn scrambled() -> TemSet {
        TemSet::from_cpu((0..5).map(|k| TemCpu::randomized(k, 0.05)).collect(), 1).unwrap()
    }

    fn run_all(store: &mut PatchStore, w: &WorldStream, tem: &TemSet) {
        loop {
            let jobs = store.next_jobs(w, 8);
            if jobs.is_empty() {
                break;
            }
            run_blocking(store, tem, jobs).unwrap();
        }
    }

    #[test]
    fn keys_nest_and_belong_to_their_tile() {
        let k = PatchKey { level: 2, x: -9, y: 17 };
        assert_eq!(k.parent(), PatchKey { level: 1, x: -5, y: 8 });
        assert_eq!(k.quadrant(), (1, 1));
        assert_eq!(k.tile(), TileCoord::new(-2, 2), "8 level-2 patches per tile side");
        let node = NodeId { tile: TileCoord::new(-1, 0), depth: 5, x: 31, y: 0 };
        let p = PatchKey::for_node(node).unwrap();
        assert_eq!((p.level, p.x, p.y), (2, -1, 0));
        assert_eq!(p.tile(), node.tile);
        assert!(PatchKey::for_node(NodeId { depth: 8, ..node }).is_none());
        assert!(PatchKey::for_node(NodeId { depth: 2, x: 0, ..node }).is_none());
    }

    /// Two neighbouring refined nodes made from different patches, in either order, share
    /// their edge exactly; the patches agree where their margins overlap; results do not
    /// depend on the order patches were made in.
    #[test]
    fn neighbouring_patches_and_nodes_agree() {
        let w = world();
        let tem = scrambled();
        // Depth-4 nodes (level 1, 8 m) on both sides of a patch border (4 nodes per patch).
        let a = NodeId { tile: TileCoord::new(0, 0), depth: 4, x: 3, y: 5 };
        let b = NodeId { x: 4, ..a };
        let (ka, kb) = (PatchKey::for_node(a).unwrap(), PatchKey::for_node(b).unwrap());
        assert_ne!(ka, kb);
        let mut s1 = PatchStore::new(0, 0);
        s1.request(ka, 0.0);
        s1.request(kb, 1.0);
        for _ in 0..3 {
            run_all(&mut s1, &w, &tem);
            s1.request(ka, 0.0);
            s1.request(kb, 1.0);
        }
        let (na, nb) = (s1.node(a, &w).unwrap(), s1.node(b, &w).unwrap());
        let mut worst = 0f32;
        for r in -1..=NODE_QUADS as i32 + 1 {
            worst = worst.max((na.at(NODE_QUADS as i32, r) - nb.at(0, r)).abs());
            worst = worst.max((na.at(NODE_QUADS as i32 + 1, r) - nb.at(1, r)).abs());
        }
        assert!(worst < 1e-3, "shared edge differs by {worst} m");
        // The raw patches agree on their overlap (margin of one = core of the other).
        let (pa, pb) = (s1.get(ka).unwrap(), s1.get(kb).unwrap());
        let mut overlap = 0f32;
        for y in 0..STORED_SIDE {
            for x in 0..2 * PATCH_MARGIN {
                overlap = overlap.max((pa[y * STORED_SIDE + PATCH + x] - pb[y * STORED_SIDE + x]).abs());
            }
        }
        assert!(overlap < 1e-3, "overlap differs by {overlap} m");
        // The other order gives the same heights.
        let mut s2 = PatchStore::new(0, 0);
        for _ in 0..3 {
            s2.request(kb, 0.0);
            run_all(&mut s2, &w, &tem);
        }
        s2.request(ka, 0.0);
        for _ in 0..3 {
            s2.request(ka, 0.0);
            run_all(&mut s2, &w, &tem);
        }
        let nb2 = s2.node(b, &w).unwrap();
        let diff = nb.heights.iter().zip(&nb2.heights).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        assert!(diff < 1e-3, "order changed heights by {diff} m");
        // And the scrambled models did refine: not plain bicubic of the 32 m surface.
        let plain = TemSet::untrained(&Exec::cpu());
        let mut s3 = PatchStore::new(0, 0);
        for _ in 0..3 {
            s3.request(kb, 0.0);
            run_all(&mut s3, &w, &plain);
        }
        let nb3 = s3.node(b, &w).unwrap();
        let moved = nb.heights.iter().zip(&nb3.heights).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        assert!(moved > 0.01, "the residual must change heights ({moved})");
    }

    /// An untrained ladder is exact bicubic (zero residual): every vertex of a refined 16 m
    /// node (apron included) equals the mean of the four bicubic ×2 pixels around its corner,
    /// computed independently from the 32 m samples with `Heightfield::upsample_bicubic`.
    #[test]
    fn untrained_refined_nodes_are_the_bicubic_surface() {
        let w = world();
        let tem = TemSet::untrained(&Exec::cpu());
        let id = NodeId { tile: TileCoord::new(0, 0), depth: 3, x: 5, y: 2 };
        let mut s = PatchStore::new(0, 0);
        s.request(PatchKey::for_node(id).unwrap(), 0.0);
        run_all(&mut s, &w, &tem);
        let d = s.node(id, &w).unwrap();
        // 32 m samples 70..110 × 22..62 hold the node (samples 80..96 × 32..48) with margin.
        let (i0, j0, side) = (70i64, 22i64, 40usize);
        let window: Vec<f32> = (0..side as i64).flat_map(|v| (0..side as i64).map(move |u| (u, v))).map(|(u, v)| w.sample(i0 + u, j0 + v).unwrap()).collect();
        let up = crate::dem::Heightfield::new(side, side, 32.0, window).upsample_bicubic(2);
        let (x0, z0) = id.origin_m();
        let mut worst = 0f32;
        for r in -1..=NODE_QUADS as i32 + 1 {
            for c in -1..=NODE_QUADS as i32 + 1 {
                // The corner at (X, Z) lies between level-0 pixels p − 1 and p, p = X / 16 + 1.
                let p = ((x0 + 16.0 * c as f64) / 16.0) as i64 + 1 - 2 * i0;
                let q = ((z0 + 16.0 * r as f64) / 16.0) as i64 + 1 - 2 * j0;
                let px = |a: i64, b: i64| up.at(a as usize, b as usize);
                let want = (px(p - 1, q - 1) + px(p, q - 1) + px(p - 1, q) + px(p, q)) * 0.25;
                worst = worst.max((d.at(c, r) - want).abs());
            }
        }
        assert!(worst < 2e-3, "refined node departs from bicubic by {worst} m");
        assert!(d.skirt_m >= 1.0 + d.max_m - d.min_m);
        assert_eq!(s.stats().quads_made, 1);
    }

    /// A refined node beside coarser neighbours (a refined one a level up and a base one):
    /// along the shared edge, whichever side is higher hangs a skirt below the other, so no
    /// crack opens. Measured with scrambled (large-residual) models.
    #[test]
    fn skirts_cover_the_gap_to_coarser_neighbours() {
        use crate::world::quadtree::NodeData;
        let w = world();
        let tem = scrambled();
        let fine = NodeId { tile: TileCoord::new(0, 0), depth: 4, x: 3, y: 2 };
        let mid = NodeId { tile: TileCoord::new(0, 0), depth: 3, x: 2, y: 1 };
        let mut s = PatchStore::new(0, 0);
        for _ in 0..3 {
            s.request(PatchKey::for_node(fine).unwrap(), 0.0);
            s.request(PatchKey::for_node(mid).unwrap(), 0.0);
            run_all(&mut s, &w, &tem);
        }
        let f = s.node(fine, &w).unwrap();
        let coarse_nodes = [s.node(mid, &w).unwrap(), NodeData::from_world(NodeId { tile: TileCoord::new(0, 0), depth: 2, x: 1, y: 0 }, &w).unwrap()];
        let mut worst_gap = 0f32;
        for c in &coarse_nodes {
            let (cx, cz) = c.id.origin_m();
            let (fx, fz) = f.id.origin_m();
            assert_eq!(cx, fx + f.id.size_m(), "they share the line x = {cx}");
            for k in 0..=NODE_QUADS {
                let z = fz + k as f64 * f.id.spacing_m();
                let t = (z - cz) / c.id.spacing_m();
                let (i, fr) = (t.floor() as i32, (t - t.floor()) as f32);
                let ch = if i >= NODE_QUADS as i32 { c.at(0, i) } else { c.at(0, i) * (1.0 - fr) + c.at(0, i + 1) * fr };
                let fh = f.at(NODE_QUADS as i32, k as i32);
                worst_gap = worst_gap.max((fh - ch).abs());
                if fh > ch {
                    assert!(fh - f.skirt_m <= ch, "crack vs {:?} at k={k}: fine {fh}, coarse {ch}, skirt {}", c.id, f.skirt_m);
                } else {
                    assert!(ch - c.skirt_m <= fh, "crack vs {:?} at k={k}: coarse {ch}, fine {fh}, skirt {}", c.id, c.skirt_m);
                }
            }
        }
        assert!(worst_gap > 0.05, "the levels must differ for this to mean something ({worst_gap})");
    }
}
