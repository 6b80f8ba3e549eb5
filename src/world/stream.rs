//! Streaming the world around the camera: a base tile's whole life in one place. Tiles are
//! wanted (near the camera), made here (with the schedule's dependencies, under a time budget
//! per frame) or as jobs in flight elsewhere ([`WorldStream::start_jobs`] →
//! [`WorldStream::finish`]), kept in a bounded cache, and evicted farthest first.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use web_time::Instant;

use super::tile::{Neighbourhood, Tile, TileSource};
use crate::grid::coord::{BASE_SPACING_M, TILE_SAMPLES, TILE_SIZE_M, TileCoord};
use crate::grid::schedule::dependencies;
use crate::queue::{Job, JobQueue, JobStats, Outcome};

/// Tile jobs a world made elsewhere keeps in flight at most (the page's worker makes one at a
/// time; a second waits in its queue so it never idles between replies).
pub const TILE_JOBS_IN_FLIGHT: usize = 2;

/// Coarse stand-ins ([`WorldStream::start_coarse_jobs`]) asked for at once: each is one 128 m
/// network tile (with its schedule's dependencies the first time), tens of milliseconds.
pub const COARSE_JOBS_IN_FLIGHT: usize = 4;

/// Far-field jobs in flight at most while tiles within the radius are still being made: the
/// horizon fills in beside them, one 128 m tile (tens of milliseconds) at a time, without
/// holding them up.
pub const FAR_JOBS_BESIDE_TILES: usize = 1;

/// How far the far field of coarse tiles reaches (metres from the eye): beyond the detailed
/// tiles, the learned world is drawn from its 128 m network tiles out to here.
pub const FAR_FIELD_M: f64 = 61_440.0;

/// Samples along a side of a coarse stand-in: the learned world's 128 m network tile.
pub const COARSE_SAMPLES: usize = crate::models::tcm::TILE_PX;

/// Tile `coord`'s far-field tile ([`COARSE_SAMPLES`]², row-major): `height` (metres) at the
/// tile's every `TILE_SAMPLES / COARSE_SAMPLES`-th global sample (x, z), so it meets the
/// tile's own samples exactly ([`TileSource::far_tile`]).
pub fn far_samples(coord: TileCoord, height: impl Fn(i64, i64) -> f32) -> Vec<f32> {
    let (n, m) = (TILE_SAMPLES as i64, COARSE_SAMPLES as i64);
    let step = n / m;
    (0..m * m).map(|k| height(coord.i as i64 * n + k % m * step, coord.j as i64 * n + k / m * step)).collect()
}

/// Whether `heights` are a whole coarse tile ([`COARSE_SAMPLES`]²) of finite heights.
fn whole_coarse(heights: &[f32]) -> bool {
    heights.len() == COARSE_SAMPLES * COARSE_SAMPLES && heights.iter().all(|h| h.is_finite())
}

/// Counters of the streamer, shown in the overlay and read by the tests.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StreamStats {
    /// Tiles generated since the world was created (dependencies included).
    pub generated: u64,
    /// Total time spent generating them (milliseconds).
    pub generate_ms: f64,
    /// Tiles evicted from the cache.
    pub evicted: u64,
    /// Wanted tiles still missing, or only standing in from an earlier world, after the last
    /// update.
    pub pending: usize,
    /// Wanted tiles with nothing to draw (not even a stale stand-in) after the last update.
    pub uncovered: usize,
    /// Tiles in the cache after the last update.
    pub cached: usize,
}

impl StreamStats {
    /// Mean generation time per tile (milliseconds), 0 before the first tile.
    pub fn ms_per_tile(&self) -> f64 {
        if self.generated == 0 { 0.0 } else { self.generate_ms / self.generated as f64 }
    }
}

/// Where a world taking over another is the same as it ([`WorldStream::take_over`]): whether
/// a tile, and whether a coarse tile, at a coordinate is unchanged.
pub type SameBeyond<'a> = (&'a dyn Fn(TileCoord) -> bool, &'a dyn Fn(TileCoord) -> bool);

/// Who makes a world's tiles.
enum Maker {
    /// A source called here, within the frame's budget.
    Here(Box<dyn TileSource>),
    /// Someone else (the page's inference worker): tiles arrive through
    /// [`WorldStream::insert`]; the string is the source's display name.
    Elsewhere(String),
}

/// The tiles of one world (seed + source) around a moving point, generated on demand.
pub struct WorldStream {
    seed: u64,
    source: Maker,
    tiles: HashMap<TileCoord, Arc<Tile>>,
    radius_tiles: f64,
    capacity: usize,
    stats: StreamStats,
    /// Tiles being made elsewhere, tagged with the world's epoch.
    jobs: JobQueue<TileCoord>,
    /// Coarse stand-ins ([`COARSE_SAMPLES`]² heights at 128 m) of tiles not drawable yet, and
    /// their jobs (the same epoch as `jobs`).
    coarse: HashMap<TileCoord, Arc<Vec<f32>>>,
    coarse_jobs: JobQueue<TileCoord>,
    /// Cached tiles of an earlier world, drawn until this world's arrive
    /// ([`take_over`](Self::take_over)): asked for like missing ones, replaced on arrival.
    stale: HashSet<TileCoord>,
}

impl WorldStream {
    /// A world of `seed` made by `source`, keeping tiles within `radius_tiles` of the camera
    /// (tile units, ≥ 1) ready to draw.
    pub fn new(seed: u64, source: Box<dyn TileSource>, radius_tiles: f64) -> Self {
        Self::with_maker(seed, Maker::Here(source), radius_tiles)
    }

    /// A world of `seed` whose tiles are made elsewhere (asynchronously) and handed in with
    /// [`insert`](Self::insert); `name` is the source's display name. [`update`](Self::update)
    /// then only counts the missing tiles and evicts.
    pub fn made_elsewhere(seed: u64, name: String, radius_tiles: f64) -> Self {
        Self::with_maker(seed, Maker::Elsewhere(name), radius_tiles)
    }

    fn with_maker(seed: u64, source: Maker, radius_tiles: f64) -> Self {
        let radius_tiles = radius_tiles.clamp(1.0, 32.0);
        let jobs = JobQueue::new(TILE_JOBS_IN_FLIGHT);
        let coarse_jobs = JobQueue::new(COARSE_JOBS_IN_FLIGHT);
        Self {
            seed,
            source,
            tiles: HashMap::new(),
            radius_tiles,
            capacity: capacity_for(radius_tiles),
            stats: StreamStats::default(),
            jobs,
            coarse: HashMap::new(),
            coarse_jobs,
            stale: HashSet::new(),
        }
    }

    /// Takes `old`'s tiles so that something stays drawn while this world's are made: `fixed`
    /// tiles (known here, e.g. pinned ones) are this world's at once; every other tile of
    /// `old` is kept as a stale stand-in and asked for again, except where `same_beyond` says
    /// this world equals `old`: a tile for which `same_beyond.0(c)` holds is kept as this
    /// world's own, and so is a coarse tile for which `same_beyond.1(c)` holds. `old`'s other
    /// coarse tiles are dropped.
    pub fn take_over(&mut self, old: WorldStream, fixed: Vec<Tile>, same_beyond: Option<SameBeyond<'_>>) {
        for (c, t) in old.tiles {
            let same = same_beyond.is_some_and(|(tile, _)| tile(c)) && !old.stale.contains(&c);
            if !same {
                self.stale.insert(c);
            }
            self.tiles.insert(c, t);
        }
        if let Some((_, coarse)) = same_beyond {
            self.coarse.extend(old.coarse.into_iter().filter(|(c, _)| coarse(*c)));
        }
        for t in fixed {
            self.stale.remove(&t.coord);
            self.tiles.insert(t.coord, Arc::new(t));
        }
        self.stats.cached = self.tiles.len();
    }

    /// Caches `tile` as a stale stand-in: drawn until this world's own arrives
    /// ([`take_over`](Self::take_over)).
    pub fn insert_stale(&mut self, tile: Tile) {
        self.stale.insert(tile.coord);
        self.tiles.insert(tile.coord, Arc::new(tile));
        self.stats.cached = self.tiles.len();
    }

    /// Whether cached tile `c` is a stale stand-in from an earlier world
    /// ([`take_over`](Self::take_over)) still waiting for this world's.
    pub fn is_stale(&self, c: TileCoord) -> bool {
        self.stale.contains(&c)
    }

    /// The same world as world `epoch` of its viewer (jobs of other epochs are stale).
    pub fn at_epoch(mut self, epoch: u64) -> Self {
        self.jobs = JobQueue::at_epoch(TILE_JOBS_IN_FLIGHT, epoch);
        self.coarse_jobs = JobQueue::at_epoch(COARSE_JOBS_IN_FLIGHT, epoch);
        self
    }

    /// The world's epoch.
    pub fn epoch(&self) -> u64 {
        self.jobs.epoch()
    }

    /// The epoch of a world that replaces this one: after this one's and at least `at_least`
    /// ([`JobQueue::new_epoch_from`]); this world's jobs in flight become stale.
    pub fn successor_epoch(&mut self, at_least: u64) -> u64 {
        let epoch = self.jobs.new_epoch_from(at_least);
        self.coarse_jobs = JobQueue::at_epoch(COARSE_JOBS_IN_FLIGHT, epoch);
        epoch
    }

    /// Starts jobs for coarse stand-ins of the nearest tiles around (x, z) metres within the
    /// radius that cannot be drawn yet and have none (nor one in flight), within
    /// [`COARSE_JOBS_IN_FLIGHT`]; each comes back through [`finish_coarse`](Self::finish_coarse)
    /// or [`fail_coarse`](Self::fail_coarse). Only for a world whose tiles are made elsewhere
    /// from 128 m network tiles (the learned world): a tile takes hundreds of milliseconds there,
    /// its 128 m tile tens.
    ///
    /// Once every tile within the radius is drawable or standing in, the far field's are
    /// asked for too: the coarse tiles beyond the radius out to [`FAR_FIELD_M`], nearest
    /// first; [`FAR_JOBS_BESIDE_TILES`] at a time while tiles within the radius are still
    /// being made (their jobs come first), as many as the queue takes once they are all made.
    pub fn start_coarse_jobs(&mut self, x_m: f64, z_m: f64) -> Vec<Job<TileCoord>> {
        let drawable = self.drawable(x_m, z_m);
        let radius = self.radius_tiles;
        let mut missing: Vec<TileCoord> =
            self.wanted(x_m, z_m).into_iter().filter(|c| c.distance_tiles(x_m, z_m) <= radius && !drawable.contains(c) && !self.coarse.contains_key(c)).collect();
        if missing.is_empty() {
            missing = self.far_ring(x_m, z_m).into_iter().filter(|c| !self.coarse.contains_key(c)).collect();
            if !self.missing(x_m, z_m).is_empty() {
                missing.truncate(FAR_JOBS_BESIDE_TILES.saturating_sub(self.coarse_jobs.stats().in_flight));
            }
        }
        self.coarse_jobs.start(missing)
    }

    /// The far field's tiles around (x, z) metres: beyond the radius, within [`FAR_FIELD_M`]
    /// (tile centres), nearest first.
    pub fn far_ring(&self, x_m: f64, z_m: f64) -> Vec<TileCoord> {
        let far = FAR_FIELD_M / TILE_SIZE_M;
        let centre = TileCoord::containing(x_m, z_m);
        let k = far.ceil() as i32 + 1;
        let mut ring: Vec<(f64, TileCoord)> = (-k..=k)
            .flat_map(|dj| (-k..=k).map(move |di| centre.offset(di, dj)))
            .map(|c| (c.distance_tiles(x_m, z_m), c))
            .filter(|(d, _)| *d > self.radius_tiles && *d <= far)
            .collect();
        ring.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        ring.into_iter().map(|(_, c)| c).collect()
    }

    /// The coarse tiles of `ring` ([`far_ring`](Self::far_ring)) that have arrived, in its
    /// order.
    pub fn far_stand_ins(&self, ring: &[TileCoord]) -> Vec<(TileCoord, Arc<Vec<f32>>)> {
        ring.iter().filter_map(|c| self.coarse.get(c).map(|h| (*c, h.clone()))).collect()
    }

    /// A coarse stand-in came back ([`COARSE_SAMPLES`]² heights, metres): kept if it belongs to
    /// this world, is still in flight, and is whole and finite. Returns whether it was kept.
    pub fn finish_coarse(&mut self, job: &Job<TileCoord>, heights: Vec<f32>) -> bool {
        if !whole_coarse(&heights) {
            self.coarse_jobs.fail(job);
            return false;
        }
        self.coarse_jobs.finish(job) != Outcome::Stale && self.insert_coarse(job.key, heights)
    }

    /// Takes a coarse tile made here ([`COARSE_SAMPLES`]² heights, metres; the procedural
    /// world's far field). Returns whether it was whole and finite, and so kept.
    pub fn insert_coarse(&mut self, c: TileCoord, heights: Vec<f32>) -> bool {
        let whole = whole_coarse(&heights);
        if whole {
            self.coarse.insert(c, Arc::new(heights));
        }
        whole
    }

    /// Whether this world's tiles are made here (by a [`TileSource`] it holds).
    pub fn made_here(&self) -> bool {
        matches!(self.source, Maker::Here(_))
    }

    /// Far-field tile `c` made by this world's own source ([`TileSource::far_tile`]), if the
    /// world is made here and its source makes them.
    pub fn far_tile_here(&self, c: TileCoord) -> Option<Vec<f32>> {
        match &self.source {
            Maker::Here(source) => source.far_tile(self.seed, c),
            Maker::Elsewhere(_) => None,
        }
    }

    /// A coarse stand-in could not be made: it may be asked for again.
    pub fn fail_coarse(&mut self, job: &Job<TileCoord>) {
        self.coarse_jobs.fail(job);
    }

    /// The coarse stand-ins to draw around (x, z) metres: tiles within the radius that cannot
    /// be drawn yet ([`drawable`](Self::drawable) is `drawable`) but have a stand-in, nearest
    /// first.
    pub fn coarse_stand_ins(&self, x_m: f64, z_m: f64, drawable: &[TileCoord]) -> Vec<(TileCoord, Arc<Vec<f32>>)> {
        self.wanted(x_m, z_m)
            .into_iter()
            .filter(|c| c.distance_tiles(x_m, z_m) <= self.radius_tiles && !drawable.contains(c))
            .filter_map(|c| self.coarse.get(&c).map(|h| (c, h.clone())))
            .collect()
    }

    /// The coarse stand-in of tile `c`, if there is one.
    pub fn coarse(&self, c: TileCoord) -> Option<&Arc<Vec<f32>>> {
        self.coarse.get(&c)
    }

    /// Counters of the tile jobs.
    pub fn job_stats(&self) -> JobStats {
        self.jobs.stats()
    }

    /// Starts jobs for the nearest missing tiles around (x, z) metres that are not in flight,
    /// within [`TILE_JOBS_IN_FLIGHT`]; each must come back through [`finish`](Self::finish)
    /// or [`fail`](Self::fail).
    pub fn start_jobs(&mut self, x_m: f64, z_m: f64) -> Vec<Job<TileCoord>> {
        let missing = self.missing(x_m, z_m);
        self.jobs.start(missing)
    }

    /// A job's tile came back: `heights` (metres, [`TILE_SAMPLES`]² row-major) made in `ms`
    /// milliseconds. Kept if it belongs to this world and is still in flight, and its heights
    /// are whole and finite (else the job failed: it may be asked for again). Returns whether
    /// it was kept.
    pub fn finish(&mut self, job: &Job<TileCoord>, heights: Vec<f32>, ms: f64) -> bool {
        if heights.len() != TILE_SAMPLES * TILE_SAMPLES || heights.iter().any(|h| !h.is_finite()) {
            self.jobs.fail(job);
            return false;
        }
        if self.jobs.finish(job) == Outcome::Stale {
            return false;
        }
        self.insert(Tile::new(job.key, heights), ms);
        true
    }

    /// A job's tile could not be made: it may be asked for again.
    pub fn fail(&mut self, job: &Job<TileCoord>) {
        self.jobs.fail(job);
    }

    /// The world's seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// The source's display name.
    pub fn source_name(&self) -> String {
        match &self.source {
            Maker::Here(s) => s.name(),
            Maker::Elsewhere(name) => name.clone(),
        }
    }

    /// Radius (tile units) within which tiles are kept ready to draw.
    pub fn radius_tiles(&self) -> f64 {
        self.radius_tiles
    }

    /// Most tiles the cache holds after an update.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Counters.
    pub fn stats(&self) -> StreamStats {
        self.stats
    }

    /// The cached tile `c`, if any.
    pub fn get(&self, c: TileCoord) -> Option<&Arc<Tile>> {
        self.tiles.get(&c)
    }

    /// Whether tile `c` is cached.
    pub fn contains(&self, c: TileCoord) -> bool {
        self.tiles.contains_key(&c)
    }

    /// Every cached tile coordinate, in no particular order.
    pub fn cached_coords(&self) -> impl Iterator<Item = TileCoord> + '_ {
        self.tiles.keys().copied()
    }

    /// Tiles to generate around world point (x, z) metres: all within the radius plus one ring
    /// (drawn tiles need their neighbours for edges and normals), nearest first.
    pub fn wanted(&self, x_m: f64, z_m: f64) -> Vec<TileCoord> {
        let centre = TileCoord::containing(x_m, z_m);
        let r = self.radius_tiles + 1.0;
        let span = r.ceil() as i32 + 1;
        let mut out: Vec<(f64, TileCoord)> = Vec::new();
        for dj in -span..=span {
            for di in -span..=span {
                let c = centre.offset(di, dj);
                let d = c.distance_tiles(x_m, z_m);
                if d <= r {
                    out.push((d, c));
                }
            }
        }
        out.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        out.into_iter().map(|(_, c)| c).collect()
    }

    /// Tiles within the radius of (x, z) metres whose eight neighbours are cached too: these
    /// can be drawn without cracks or one-sided normals.
    pub fn drawable(&self, x_m: f64, z_m: f64) -> Vec<TileCoord> {
        self.wanted(x_m, z_m).into_iter().filter(|c| c.distance_tiles(x_m, z_m) <= self.radius_tiles).filter(|c| c.window3x3().iter().all(|n| self.tiles.contains_key(n))).collect()
    }

    /// Generates missing wanted tiles around (x, z) metres, nearest first, until `budget_ms`
    /// has been spent (at least one tile per call), then evicts the farthest tiles beyond the
    /// cache capacity. Returns the tiles generated by this call.
    pub fn update(&mut self, x_m: f64, z_m: f64, budget_ms: f64) -> Vec<TileCoord> {
        let start = Instant::now();
        let wanted = self.wanted(x_m, z_m);
        let mut made = Vec::new();
        if matches!(self.source, Maker::Here(_)) {
            for &c in &wanted {
                if self.tiles.contains_key(&c) && !self.stale.contains(&c) {
                    continue;
                }
                if !made.is_empty() && start.elapsed().as_secs_f64() * 1e3 >= budget_ms {
                    break;
                }
                self.ensure_into(c, &mut made);
            }
        }
        self.stats.pending = wanted.iter().filter(|c| !self.tiles.contains_key(c) || self.stale.contains(c)).count();
        self.stats.uncovered = wanted.iter().filter(|c| !self.tiles.contains_key(c)).count();
        self.evict(x_m, z_m);
        self.stats.cached = self.tiles.len();
        made
    }

    /// Wanted tiles around (x, z) metres that are not cached or only stale, nearest first:
    /// what to ask of a source that works elsewhere.
    pub fn missing(&self, x_m: f64, z_m: f64) -> Vec<TileCoord> {
        self.wanted(x_m, z_m).into_iter().filter(|c| !self.tiles.contains_key(c) || self.stale.contains(c)).collect()
    }

    /// Takes a tile made elsewhere in `ms` milliseconds (it replaces a cached one of the same
    /// coordinate, stale or not). The caller makes sure it belongs to this world
    /// ([`finish`](Self::finish) does).
    pub fn insert(&mut self, tile: Tile, ms: f64) {
        self.stale.remove(&tile.coord);
        self.stats.generate_ms += ms;
        self.stats.generated += 1;
        self.tiles.insert(tile.coord, Arc::new(tile));
        self.stats.cached = self.tiles.len();
    }

    /// Returns tile `c`, generating it and (for sources that read neighbours) the tiles the
    /// schedule makes it depend on. The result depends only on (seed, source, c).
    ///
    /// # Panics
    /// For a world whose tiles are made elsewhere, if `c` is not cached.
    pub fn ensure(&mut self, c: TileCoord) -> Arc<Tile> {
        let mut made = Vec::new();
        self.ensure_into(c, &mut made)
    }

    fn ensure_into(&mut self, c: TileCoord, made: &mut Vec<TileCoord>) -> Arc<Tile> {
        if let Some(t) = self.tiles.get(&c).filter(|_| !self.stale.contains(&c)) {
            return t.clone();
        }
        let Maker::Here(source) = &self.source else { panic!("tile {c:?} is made elsewhere and has not arrived") };
        let mut inputs: [Option<Arc<Tile>>; 9] = Default::default();
        if source.uses_neighbours() {
            for d in dependencies(c) {
                let k = ((d.j - c.j + 1) * 3 + (d.i - c.i + 1)) as usize;
                inputs[k] = Some(self.ensure_into(d, made));
            }
        }
        let mut nb = Neighbourhood::default();
        for (slot, t) in nb.tiles.iter_mut().zip(inputs.iter()) {
            *slot = t.as_deref();
        }
        let t0 = Instant::now();
        let Maker::Here(source) = &self.source else { unreachable!("checked above") };
        let tile = Arc::new(source.generate(self.seed, c, &nb));
        self.stats.generate_ms += t0.elapsed().as_secs_f64() * 1e3;
        self.stats.generated += 1;
        self.tiles.insert(c, tile.clone());
        self.stale.remove(&c);
        made.push(c);
        tile
    }

    fn evict(&mut self, x_m: f64, z_m: f64) {
        // Stand-ins are only wanted while their tile cannot be drawn.
        // The far field's are kept out to a tile beyond its reach.
        if !self.coarse.is_empty() {
            let (radius, far, tiles) = (self.radius_tiles, FAR_FIELD_M / TILE_SIZE_M + 1.0, &self.tiles);
            self.coarse.retain(|c, _| {
                let d = c.distance_tiles(x_m, z_m);
                d <= far && (d > radius || !c.window3x3().iter().all(|n| tiles.contains_key(n)))
            });
        }
        if self.tiles.len() <= self.capacity {
            return;
        }
        let mut by_distance: Vec<(f64, TileCoord)> = self.tiles.keys().map(|c| (c.distance_tiles(x_m, z_m), *c)).collect();
        by_distance.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let excess = self.tiles.len() - self.capacity;
        for (_, c) in by_distance.into_iter().take(excess) {
            self.tiles.remove(&c);
            self.stale.remove(&c);
            self.stats.evicted += 1;
        }
    }

    /// Height (metres) at world point (x, z) by bilinear interpolation of cached samples;
    /// `None` where the needed tiles are not cached.
    pub fn height_at(&self, x_m: f64, z_m: f64) -> Option<f32> {
        let gx = x_m / BASE_SPACING_M;
        let gz = z_m / BASE_SPACING_M;
        let (x0, z0) = (gx.floor() as i64, gz.floor() as i64);
        let (fx, fz) = ((gx - x0 as f64) as f32, (gz - z0 as f64) as f32);
        let s = |x: i64, z: i64| self.sample(x, z);
        let (h00, h10, h01, h11) = (s(x0, z0)?, s(x0 + 1, z0)?, s(x0, z0 + 1)?, s(x0 + 1, z0 + 1)?);
        let a = h00 + (h10 - h00) * fx;
        let b = h01 + (h11 - h01) * fx;
        Some(a + (b - a) * fz)
    }

    /// Height (metres) of the global sample (gx, gz) (sample units: 32 m), if its tile is cached.
    pub fn sample(&self, gx: i64, gz: i64) -> Option<f32> {
        let n = TILE_SAMPLES as i64;
        let c = TileCoord::new(gx.div_euclid(n) as i32, gz.div_euclid(n) as i32);
        let t = self.tiles.get(&c)?;
        Some(t.at(gx.rem_euclid(n) as usize, gz.rem_euclid(n) as usize))
    }
}

/// Cache capacity for a radius: every tile within radius + 3 of any point, so wanted tiles and
/// their dependencies are never evicted while the camera stays put.
fn capacity_for(radius_tiles: f64) -> usize {
    let side = 2 * (radius_tiles.ceil() as usize + 4) + 1;
    side * side
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::coord::TILE_SIZE_M;
    use crate::world::noise::ProceduralSource;

    /// A source that really reads its neighbours: its tile is its own noise plus the mean of
    /// the facing border rows of every input neighbour. Any dependence on visit order would
    /// show up in its output.
    struct BorderMean(ProceduralSource);

    impl TileSource for BorderMean {
        fn name(&self) -> String {
            "border-mean".into()
        }
        fn uses_neighbours(&self) -> bool {
            true
        }
        fn generate(&self, seed: u64, c: TileCoord, nb: &Neighbourhood<'_>) -> Tile {
            let mut t = self.0.generate(seed, c, nb);
            let mut acc = 0f32;
            for dj in -1..=1 {
                for di in -1..=1 {
                    if let Some(n) = nb.get(di, dj) {
                        acc += n.heights.iter().step_by(7).sum::<f32>() / 1000.0 + n.at(0, 0);
                    }
                }
            }
            for h in &mut t.heights {
                *h += acc;
            }
            Tile::new(c, t.heights)
        }
    }

    /// A world made elsewhere that takes over an earlier one: the fixed tile is this world's
    /// at once (not asked for), the earlier world's other tiles stay drawable as stale
    /// stand-ins and are asked for again (pending until they arrive, then replaced and no
    /// longer stale); where the two worlds are the same, tiles and coarse tiles are kept as
    /// this world's and not asked for.
    #[test]
    fn a_world_taking_over_keeps_the_old_tiles_drawable_until_its_own_replace_them() {
        let source = ProceduralSource::default();
        let mut old = WorldStream::new(3, Box::new(ProceduralSource::default()), 1.0);
        let (x, z) = (TILE_SIZE_M * 0.5, TILE_SIZE_M * 0.5);
        while !old.update(x, z, 1e9).is_empty() {}
        let cached: Vec<TileCoord> = old.cached_coords().collect();
        assert!(cached.len() >= 9 && old.drawable(x, z).contains(&TileCoord::new(0, 0)));
        old.insert_coarse(TileCoord::new(9, 0), vec![1.0; COARSE_SAMPLES * COARSE_SAMPLES]);
        old.insert_coarse(TileCoord::new(1, 0), vec![1.0; COARSE_SAMPLES * COARSE_SAMPLES]);
        let mut new = WorldStream::made_elsewhere(3, "pinned".into(), 1.0);
        let fixed = Tile::new(TileCoord::new(0, 0), vec![5.0; TILE_SAMPLES * TILE_SAMPLES]);
        let beyond = |c: TileCoord| c.i >= 2;
        let coarse_beyond = |c: TileCoord| c.i >= 5;
        new.take_over(old, vec![fixed], Some((&beyond, &coarse_beyond)));
        assert_eq!(new.get(TileCoord::new(0, 0)).unwrap().heights[0], 5.0);
        assert!(!new.is_stale(TileCoord::new(0, 0)) && new.is_stale(TileCoord::new(1, 1)) && new.is_stale(TileCoord::new(-1, 0)));
        assert!(!new.is_stale(TileCoord::new(2, 0)), "beyond the reach a tile is this world's");
        assert!(new.coarse(TileCoord::new(9, 0)).is_some() && new.coarse(TileCoord::new(1, 0)).is_none());
        assert!(new.drawable(x, z).contains(&TileCoord::new(0, 0)), "drawable at once over stale neighbours");
        let missing = new.missing(x, z);
        assert!(!missing.contains(&TileCoord::new(0, 0)) && !missing.contains(&TileCoord::new(2, 0)));
        assert!(missing.contains(&TileCoord::new(1, 1)) && missing.contains(&TileCoord::new(-1, -1)));
        new.update(x, z, 0.0);
        assert_eq!(new.stats().pending, missing.len());
        assert_eq!(new.stats().uncovered, 0, "every wanted tile has a stand-in");
        let jobs = new.start_jobs(x, z);
        assert_eq!(jobs.len(), TILE_JOBS_IN_FLIGHT);
        for job in &jobs {
            let heights = source.generate(4, job.key, &Neighbourhood::default()).heights;
            assert!(new.finish(job, heights.clone(), 1.0));
            assert!(!new.is_stale(job.key));
            assert_eq!(new.get(job.key).unwrap().heights, heights);
        }
        new.update(x, z, 0.0);
        assert_eq!(new.stats().pending, missing.len() - jobs.len());
        // Without a same region every old tile is stale and no coarse tile is kept.
        let mut other = WorldStream::made_elsewhere(3, "other".into(), 1.0);
        other.take_over(new, vec![], None);
        assert!(cached.iter().all(|c| other.is_stale(*c)) && other.coarse(TileCoord::new(9, 0)).is_none());
    }

    fn neighbour_world() -> WorldStream {
        WorldStream::new(77, Box::new(BorderMean(ProceduralSource::default())), 1.0)
    }

    #[test]
    fn schedule_is_pure_whatever_the_visit_order() {
        let coords: Vec<TileCoord> = (-2..3).flat_map(|j| (-2..3).map(move |i| TileCoord::new(i, j))).collect();
        let mut forward = neighbour_world();
        let a: Vec<Arc<Tile>> = coords.iter().map(|&c| forward.ensure(c)).collect();
        let mut backward = neighbour_world();
        for &c in coords.iter().rev() {
            backward.ensure(c);
        }
        // A third order: a flight that sweeps far away (evicting everything) and comes back.
        let mut flight = neighbour_world();
        for step in 0..40 {
            let x = (step as f64 - 20.0).abs() * TILE_SIZE_M * 0.7;
            flight.update(x, -x * 0.5, 1e9);
        }
        for (k, &c) in coords.iter().enumerate() {
            let b = backward.ensure(c);
            let f = flight.ensure(c);
            assert!(a[k].heights.iter().zip(&b.heights).all(|(x, y)| x.to_bits() == y.to_bits()), "{c:?} differs (reverse order)");
            assert!(a[k].heights.iter().zip(&f.heights).all(|(x, y)| x.to_bits() == y.to_bits()), "{c:?} differs (flight order)");
        }
        assert!(flight.stats().evicted > 0, "the flight must have evicted tiles");
    }

    #[test]
    fn neighbours_change_the_tile_so_the_purity_test_is_meaningful() {
        let mut w = neighbour_world();
        let with = w.ensure(TileCoord::new(1, 1));
        let alone = ProceduralSource::default().generate(77, TileCoord::new(1, 1), &Neighbourhood::default());
        assert_ne!(with.heights[0], alone.heights[0]);
        // (1,1) depends on all eight neighbours: they were generated too.
        assert_eq!(w.stats().generated, 9);
    }

    /// On a 60-tile flight the cache never holds more than its capacity, yet it visits far
    /// more tiles than that (so eviction did the bounding), and eviction never takes a tile
    /// the view needs: after every update every wanted tile is cached.
    #[test]
    fn cache_stays_bounded_on_a_long_flight() {
        let mut w = WorldStream::new(5, Box::new(ProceduralSource::default()), 2.0);
        let mut visited = std::collections::HashSet::new();
        for step in 0..60 {
            let (x, z) = (step as f64 * TILE_SIZE_M * 0.9, step as f64 * TILE_SIZE_M * 0.27);
            w.update(x, z, 1e9);
            visited.extend(w.cached_coords());
            assert!(w.stats().cached <= w.capacity(), "step {step}: {} > {}", w.stats().cached, w.capacity());
            assert!(w.wanted(x, z).iter().all(|c| w.contains(*c)), "step {step}: a wanted tile is not cached");
            assert!(!w.drawable(x, z).is_empty());
        }
        assert!(visited.len() > 2 * w.capacity(), "{} tiles visited, capacity {}", visited.len(), w.capacity());
        assert_eq!(w.stats().evicted as usize, w.stats().generated as usize - w.stats().cached);
    }

    #[test]
    fn time_budget_limits_work_per_update() {
        let mut w = WorldStream::new(5, Box::new(ProceduralSource::default()), 3.0);
        let made = w.update(100.0, 100.0, 0.0);
        assert_eq!(made, vec![TileCoord::new(0, 0)], "a zero budget still makes progress, one tile per call, nearest first");
        assert!(w.stats().pending > 10);
        let made = w.update(100.0, 100.0, 1e9);
        assert_eq!(made.len(), w.stats().cached - 1, "an ample budget makes all the rest");
        assert_eq!(w.stats().pending, 0);
    }

    #[test]
    fn height_query_interpolates_cached_samples() {
        let mut w = WorldStream::new(3, Box::new(ProceduralSource::default()), 1.0);
        assert_eq!(w.height_at(10.0, 10.0), None);
        w.update(0.0, 0.0, 1e9);
        let exact = w.sample(3, 4).unwrap();
        assert_eq!(w.height_at(3.0 * BASE_SPACING_M, 4.0 * BASE_SPACING_M), Some(exact));
        let mid = w.height_at(3.5 * BASE_SPACING_M, 4.0 * BASE_SPACING_M).unwrap();
        let (a, b) = (exact, w.sample(4, 4).unwrap());
        assert!((mid - (a + b) / 2.0).abs() < 1e-3);
        assert!(w.height_at(-20.0, -20.0).is_some(), "negative coordinates read tile (-1,-1)");
    }

    /// Coarse first, then the horizon beside the tiles: a world made elsewhere asks for the
    /// stand-ins within the radius first; once each has one, far-field tiles come one at a
    /// time (nearest first, none while one is in flight) while tiles within the radius are
    /// being made, and up to the queue's limit once they are all made.
    #[test]
    fn far_field_jobs_go_one_at_a_time_beside_the_tiles_and_all_at_once_after() {
        let mut w = WorldStream::made_elsewhere(1, "elsewhere".into(), 1.0);
        let (x, z) = (2048.0, 2048.0);
        let near = w.start_coarse_jobs(x, z);
        assert!(!near.is_empty() && near.iter().all(|j| j.key.distance_tiles(x, z) <= 1.0), "{near:?}");
        let mut jobs = near;
        let far = loop {
            if jobs.iter().any(|j| j.key.distance_tiles(x, z) > 1.0) {
                break jobs;
            }
            for j in &jobs {
                assert!(w.finish_coarse(j, vec![1.0; COARSE_SAMPLES * COARSE_SAMPLES]));
            }
            jobs = w.start_coarse_jobs(x, z);
        };
        assert!(far.iter().all(|j| j.key.distance_tiles(x, z) > 1.0), "the far field only once each tile within the radius stands in");
        let ring = w.far_ring(x, z);
        assert!(!w.missing(x, z).is_empty(), "the tiles are not made yet");
        let first_far = far.iter().find(|j| j.key.distance_tiles(x, z) > 1.0).expect("a far job beside the tiles");
        assert_eq!(far.iter().filter(|j| j.key.distance_tiles(x, z) > 1.0).count(), FAR_JOBS_BESIDE_TILES);
        assert!(ring[..FAR_JOBS_BESIDE_TILES + 1].contains(&first_far.key), "nearest first");
        assert!(w.start_coarse_jobs(x, z).is_empty(), "none while one is in flight");
        assert!(w.finish_coarse(first_far, vec![1.0; COARSE_SAMPLES * COARSE_SAMPLES]));
        assert_eq!(w.start_coarse_jobs(x, z).len(), FAR_JOBS_BESIDE_TILES, "the next one");
        for c in w.missing(x, z) {
            w.insert(Tile::new(c, vec![0.0; TILE_SAMPLES * TILE_SAMPLES]), 1.0);
        }
        let after = w.start_coarse_jobs(x, z);
        assert_eq!(after.len() + FAR_JOBS_BESIDE_TILES, COARSE_JOBS_IN_FLIGHT, "the queue's limit once the tiles are made");
    }
}
