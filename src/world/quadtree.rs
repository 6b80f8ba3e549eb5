//! Per-tile quadtree level of detail: node identities, the height data a node holds (base
//! samples now, refined heights from the TEM later), the node cache, and the selection of the
//! nodes to draw for a view (screen-space error + 3-D frustum culling).

use std::collections::HashMap;
use std::sync::Arc;

use glam::{DVec3, Mat4, Vec3, Vec4};

use super::refine::{PATCH_MARGIN, PatchKey, PatchStore, STORED_SIDE};
use super::stream::WorldStream;
use crate::grid::coord::{TILE_SAMPLES, TILE_SIZE_M, TileCoord};
use crate::models::tem::{LEVELS, PATCH};

/// Quads along one side of every node's mesh, at every depth.
pub const NODE_QUADS: usize = 32;

/// Vertices along one side of a node's grid (`NODE_QUADS` + 1).
pub const NODE_GRID: usize = NODE_QUADS + 1;

/// Side of a node's height array: the grid plus a one-sample apron on each side for normals.
pub const NODE_APRON_GRID: usize = NODE_GRID + 2;

/// Deepest node that base tile samples can fill: at depth 2 a node's vertex spacing equals the
/// base spacing (128 samples / 2² / 32 quads = 1 sample per quad, 32 m). Deeper nodes need
/// refined heights (TEM).
pub const BASE_DATA_DEPTH: u8 = 2;

/// Identity of a quadtree node: tile, depth (0 = whole tile) and position (x along +x, y along
/// +z, each in 0..2^depth) among the nodes of that depth.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId {
    /// The tile this node subdivides.
    pub tile: TileCoord,
    /// Depth below the tile's root (0 = the tile).
    pub depth: u8,
    /// Column among nodes of this depth (+x).
    pub x: u32,
    /// Row among nodes of this depth (+z).
    pub y: u32,
}

impl NodeId {
    /// The root node of `tile`.
    pub const fn root(tile: TileCoord) -> Self {
        Self { tile, depth: 0, x: 0, y: 0 }
    }

    /// The four children in row-major order (NW, NE, SW, SE).
    pub fn children(self) -> [NodeId; 4] {
        let (d, x, y) = (self.depth + 1, self.x * 2, self.y * 2);
        [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(a, b)| NodeId { tile: self.tile, depth: d, x: x + a, y: y + b })
    }

    /// Side length (metres).
    pub fn size_m(self) -> f64 {
        TILE_SIZE_M / (1u64 << self.depth) as f64
    }

    /// Distance between neighbouring vertices of its mesh (metres).
    pub fn spacing_m(self) -> f64 {
        self.size_m() / NODE_QUADS as f64
    }

    /// World position (x, z) metres of its north-west corner.
    pub fn origin_m(self) -> (f64, f64) {
        let (tx, tz) = self.tile.origin_m();
        (tx + self.x as f64 * self.size_m(), tz + self.y as f64 * self.size_m())
    }
}

/// The heights of one node: a `NODE_APRON_GRID`² array (metres) whose inner `NODE_GRID`² are
/// the mesh vertices at `id.spacing_m()` spacing, plus what culling and crack hiding need.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeData {
    /// Which node.
    pub id: NodeId,
    /// Heights (metres), row-major, index `(r + 1) * NODE_APRON_GRID + (c + 1)` for vertex
    /// (c, r), c and r in −1..=NODE_QUADS + 1.
    pub heights: Vec<f32>,
    /// Lowest vertex height (metres).
    pub min_m: f32,
    /// Highest vertex height (metres).
    pub max_m: f32,
    /// How far the skirts hang below the edges (metres): at least the height range of the
    /// finest known samples along any edge, which bounds the gap to any neighbour's edge.
    pub skirt_m: f32,
    /// Content version: unique to every node data built in this process (a clone keeps it),
    /// so caches keyed by (id, version) never take a rebuilt node for an older one.
    pub version: u64,
    /// Vertices per drawn quad along each side ([`DRAW_STRIDES`]): 1 draws every vertex; the
    /// far field's nodes draw every 4th (their vertices are far apart on screen).
    pub stride: u8,
}

/// The grid strides a node may be drawn with ([`NodeData::stride`]).
pub const DRAW_STRIDES: [u8; 2] = [1, 4];

/// The next [`NodeData::version`].
fn next_version() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
    NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

impl NodeData {
    /// Height (metres) of grid vertex (c, r), each in −1..=NODE_QUADS + 1.
    pub fn at(&self, c: i32, r: i32) -> f32 {
        self.heights[((r + 1) as usize) * NODE_APRON_GRID + (c + 1) as usize]
    }

    /// Builds a node of depth ≤ `BASE_DATA_DEPTH` from base tile samples. `None` if a needed
    /// tile (the node's own or a neighbour, for edges and normals) is not cached, or if the
    /// node is deeper than the base data.
    pub fn from_world(id: NodeId, world: &WorldStream) -> Option<NodeData> {
        if id.depth > BASE_DATA_DEPTH {
            return None;
        }
        let n = TILE_SAMPLES as i64;
        let node_samples = n >> id.depth;
        let step = node_samples / NODE_QUADS as i64;
        let gx0 = id.tile.i as i64 * n + id.x as i64 * node_samples;
        let gz0 = id.tile.j as i64 * n + id.y as i64 * node_samples;
        let mut heights = Vec::with_capacity(NODE_APRON_GRID * NODE_APRON_GRID);
        for r in -1..=(NODE_QUADS as i64 + 1) {
            for c in -1..=(NODE_QUADS as i64 + 1) {
                heights.push(world.sample(gx0 + c * step, gz0 + r * step)?);
            }
        }
        // Range of the finest samples along each edge: any neighbour's edge polyline is an
        // interpolation of these same samples, so it stays inside that range.
        let mut skirt = 0f32;
        for edge in 0..4 {
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for k in 0..=node_samples {
                let (gx, gz) = match edge {
                    0 => (gx0 + k, gz0),
                    1 => (gx0 + k, gz0 + node_samples),
                    2 => (gx0, gz0 + k),
                    _ => (gx0 + node_samples, gz0 + k),
                };
                let h = world.sample(gx, gz)?;
                lo = lo.min(h);
                hi = hi.max(h);
            }
            skirt = skirt.max(hi - lo);
        }
        Some(NodeData::new(id, heights, skirt + 1.0))
    }

    /// The root node of tile `tile` from its coarse stand-in ([`WorldStream::coarse`]: the
    /// 128 m network tile, whose sample k lies on vertex k of a root node), the edges and the
    /// apron from the neighbours' stand-ins or tiles where there are some (else the tile's own
    /// edge). Its skirts hang 30 m plus its height range: a temporary picture, drawn until the
    /// tile and its neighbours are made, or a far-field tile (drawn with `stride`). `None`
    /// without a stand-in.
    pub fn from_coarse(tile: TileCoord, world: &WorldStream, stride: u8) -> Option<NodeData> {
        use crate::world::stream::COARSE_SAMPLES;
        let own = world.coarse(tile)?;
        let n = COARSE_SAMPLES as i64;
        let per_sample = TILE_SAMPLES as i64 / n;
        let height = |c: i64, r: i64| -> f32 {
            let (gc, gr) = (tile.i as i64 * n + c, tile.j as i64 * n + r);
            let t = TileCoord::new(gc.div_euclid(n) as i32, gr.div_euclid(n) as i32);
            if let Some(h) = world.coarse(t) {
                return h[(gr.rem_euclid(n) * n + gc.rem_euclid(n)) as usize];
            }
            world.sample(gc * per_sample, gr * per_sample).unwrap_or_else(|| own[(r.clamp(0, n - 1) * n + c.clamp(0, n - 1)) as usize])
        };
        let mut heights = Vec::with_capacity(NODE_APRON_GRID * NODE_APRON_GRID);
        for r in -1..=(NODE_QUADS as i64 + 1) {
            for c in -1..=(NODE_QUADS as i64 + 1) {
                heights.push(height(c, r));
            }
        }
        let mut d = NodeData::new(NodeId::root(tile), heights, 0.0);
        d.skirt_m = 30.0 + (d.max_m - d.min_m);
        d.stride = stride;
        Some(d)
    }

    /// Wraps an apron height array (metres) as node `id` with skirts of `skirt_m` metres.
    pub fn new(id: NodeId, heights: Vec<f32>, skirt_m: f32) -> NodeData {
        assert_eq!(heights.len(), NODE_APRON_GRID * NODE_APRON_GRID);
        let (mut min_m, mut max_m) = (f32::INFINITY, f32::NEG_INFINITY);
        for r in 0..NODE_GRID {
            for c in 0..NODE_GRID {
                let h = heights[(r + 1) * NODE_APRON_GRID + c + 1];
                min_m = min_m.min(h);
                max_m = max_m.max(h);
            }
        }
        NodeData { id, heights, min_m, max_m, skirt_m, version: next_version(), stride: 1 }
    }

    /// World-space bounding box (metres) including the skirts.
    pub fn bounds_m(&self) -> (DVec3, DVec3) {
        let (x, z) = self.id.origin_m();
        let s = self.id.size_m();
        (DVec3::new(x, (self.min_m - self.skirt_m) as f64, z), DVec3::new(x + s, self.max_m as f64, z + s))
    }
}

/// A view frustum as six planes (a·x + b·y + c·z + d ≥ 0 inside) in camera-relative
/// coordinates (metres, the eye at the origin).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frustum {
    /// Left, right, bottom, top, near, far.
    pub planes: [Vec4; 6],
}

impl Frustum {
    /// The frustum of a camera-relative view-projection matrix (wgpu clip space, depth 0..1).
    pub fn from_view_proj(m: Mat4) -> Frustum {
        let r = [m.row(0), m.row(1), m.row(2), m.row(3)];
        let planes = [r[3] + r[0], r[3] - r[0], r[3] + r[1], r[3] - r[1], r[2], r[3] - r[2]];
        Frustum { planes: planes.map(|p| p / p.truncate().length()) }
    }

    /// Whether the box [min, max] (camera-relative metres) may be visible: false only when it
    /// lies entirely outside one plane.
    pub fn intersects_box(&self, min: Vec3, max: Vec3) -> bool {
        self.planes.iter().all(|p| {
            let v = Vec3::new(if p.x >= 0.0 { max.x } else { min.x }, if p.y >= 0.0 { max.y } else { min.y }, if p.z >= 0.0 { max.z } else { min.z });
            p.truncate().dot(v) + p.w >= 0.0
        })
    }
}

/// What node selection needs to know about the view.
#[derive(Clone, Copy, Debug)]
pub struct LodView {
    /// Eye position (world metres).
    pub eye_m: DVec3,
    /// Frustum (camera-relative).
    pub frustum: Frustum,
    /// Pixels per radian at the screen centre (viewport height / 2 / tan(fov_y / 2)).
    pub pixels_per_radian: f64,
    /// Target projected vertex spacing (pixels): a node splits while its vertex spacing
    /// projects larger than this. Smaller means more detail.
    pub target_px: f64,
    /// Deepest depth to use.
    pub max_depth: u8,
}

/// A node below the base depth is refined only if its height range is at least this many
/// times its vertex spacing ("rough enough"): flat ground gains nothing from the TEM.
pub const ROUGHNESS_PER_SPACING: f32 = 0.5;

/// Distance (metres) from `p` to the box [min, max]; 0 inside.
fn distance_to_box(p: DVec3, min: DVec3, max: DVec3) -> f64 {
    (min - p).max(p - max).max(DVec3::ZERO).length()
}

/// Whether node data `d` is coarse for `view`: its vertex spacing projects to more than the
/// target number of pixels at its nearest point.
pub fn wants_split(d: &NodeData, view: &LodView) -> bool {
    let (min, max) = d.bounds_m();
    let dist = distance_to_box(view.eye_m, min, max).max(1.0);
    d.id.spacing_m() * view.pixels_per_radian / dist > view.target_px
}

/// Cache of built nodes, keyed by node; nodes leave with their tile.
#[derive(Default)]
pub struct NodeCache {
    nodes: HashMap<NodeId, Arc<NodeData>>,
    /// Nodes built since creation.
    pub built: u64,
}

impl NodeCache {
    /// An empty cache.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of cached nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Whether no node is cached.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// The cached node `id`.
    pub fn get(&self, id: NodeId) -> Option<&Arc<NodeData>> {
        self.nodes.get(&id)
    }

    /// Stores node data that arrived from elsewhere (e.g. refined heights from the TEM),
    /// replacing what was cached for that node.
    pub fn insert(&mut self, data: NodeData) -> Arc<NodeData> {
        let d = Arc::new(data);
        self.nodes.insert(d.id, d.clone());
        d
    }

    /// Node `id` from the cache, else built while `build_budget` (nodes) lasts: from base
    /// samples down to `BASE_DATA_DEPTH`, below that from refined patches in `refine`.
    pub fn get_or_build(&mut self, id: NodeId, world: &WorldStream, refine: Option<&PatchStore>, build_budget: &mut usize) -> Option<Arc<NodeData>> {
        if let Some(d) = self.nodes.get(&id) {
            return Some(d.clone());
        }
        if *build_budget == 0 {
            return None;
        }
        let d = if id.depth <= BASE_DATA_DEPTH { NodeData::from_world(id, world)? } else { NodeData::from_patches(id, refine?, world)? };
        *build_budget -= 1;
        self.built += 1;
        Some(self.insert(d))
    }

    /// Drops every node deeper than `depth`.
    pub fn retain_depth(&mut self, depth: u8) {
        self.nodes.retain(|id, _| id.depth <= depth);
    }

    /// Drops every node whose tile is not in `keep`; returns the dropped ids.
    pub fn retain_tiles(&mut self, keep: impl Fn(TileCoord) -> bool) -> Vec<NodeId> {
        let gone: Vec<NodeId> = self.nodes.keys().filter(|id| !keep(id.tile)).copied().collect();
        for id in &gone {
            self.nodes.remove(id);
        }
        gone
    }

    /// The nodes to draw for `view` over `tiles`: for each tile, descend while a node is in the
    /// frustum, coarse for the view and all four children are available (built within
    /// `build_budget` nodes this call); otherwise draw the node itself. Below the base depth a
    /// node also has to be rough enough ([`ROUGHNESS_PER_SPACING`]); the refined patch its
    /// children need is requested from `refine` (nearest first) when missing. Nodes outside the
    /// frustum are skipped. Every visible part of every tile is covered exactly once. The
    /// store's earlier requests are replaced by this view's.
    pub fn select(&mut self, tiles: &[TileCoord], world: &WorldStream, mut refine: Option<&mut PatchStore>, view: &LodView, build_budget: &mut usize) -> Vec<Arc<NodeData>> {
        if let Some(store) = refine.as_deref_mut() {
            store.clear_requests();
        }
        let mut out = Vec::new();
        for &t in tiles {
            if let Some(root) = self.get_or_build(NodeId::root(t), world, None, build_budget) {
                self.visit(root, world, &mut refine, view, build_budget, &mut out);
            }
        }
        out
    }

    fn visit(&mut self, d: Arc<NodeData>, world: &WorldStream, refine: &mut Option<&mut PatchStore>, view: &LodView, budget: &mut usize, out: &mut Vec<Arc<NodeData>>) {
        let (min, max) = d.bounds_m();
        let rel = |p: DVec3| (p - view.eye_m).as_vec3();
        if !view.frustum.intersects_box(rel(min), rel(max)) {
            return;
        }
        let refining = d.id.depth >= BASE_DATA_DEPTH;
        let rough = !refining || d.max_m - d.min_m >= ROUGHNESS_PER_SPACING * d.id.spacing_m() as f32;
        if d.id.depth < view.max_depth && rough && wants_split(&d, view) {
            let kids = d.id.children();
            let store = refine.as_deref();
            let built: Vec<Arc<NodeData>> = kids.iter().filter_map(|&k| self.get_or_build(k, world, store, budget)).collect();
            if built.len() == 4 {
                for k in built {
                    self.visit(k, world, refine, view, budget, out);
                }
                return;
            }
            if refining && let (Some(store), Some(key)) = (refine.as_deref_mut(), kids[0].patch()) {
                store.request(key, distance_to_box(view.eye_m, min, max));
            }
        }
        out.push(d);
    }
}

/// Level-k nodes are this much deeper than the level: a depth-(k + 3) node has the vertex
/// spacing of level k (16 m at depth 3 … 1 m at depth 7).
pub const DEPTH_OF_LEVEL_0: u8 = BASE_DATA_DEPTH + 1;

/// Refined nodes: which TEM patch a node reads, and the node built from it.
impl NodeId {
    /// The patch whose data a refined node uses, and the level: `None` above the refined
    /// depths or below the last level.
    pub fn patch(self) -> Option<PatchKey> {
        let level = self.depth.checked_sub(DEPTH_OF_LEVEL_0)? as usize;
        if level >= LEVELS {
            return None;
        }
        let (gx, gz) = self.global();
        let per_patch = (PATCH / NODE_QUADS) as i64;
        Some(PatchKey { level: level as u8, x: gx.div_euclid(per_patch), y: gz.div_euclid(per_patch) })
    }

    /// Global index (x, z) of the node among all nodes of its depth.
    fn global(self) -> (i64, i64) {
        let n = 1i64 << self.depth;
        (self.tile.i as i64 * n + self.x as i64, self.tile.j as i64 * n + self.y as i64)
    }
}

impl NodeData {
    /// Builds refined node `id` (depth 3 … 7) from its patch in `store`: every vertex the mean of
    /// the four pixels around its corner. `None` if the patch is not stored. Skirts hang 1 m +
    /// the node's height range + twice its largest edge departure from the 32 m surface below
    /// the edges, which covers the gap to any coarser neighbour (whose edge lies between the
    /// 32 m surface and its own refinement).
    pub fn from_patches(id: NodeId, store: &PatchStore, world: &WorldStream) -> Option<NodeData> {
        let key = id.patch()?;
        let patch = store.get(key)?;
        let (gx, gz) = id.global();
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::coord::BASE_SPACING_M;
    use crate::models::tem::{Exec, TemSet};
    use crate::world::noise::ProceduralSource;
    use crate::world::refine::tests::{run_all, scrambled, world as patch_world};

    fn world() -> WorldStream {
        let mut w = WorldStream::new(11, Box::new(ProceduralSource::default()), 2.0);
        w.update(TILE_SIZE_M * 0.5, TILE_SIZE_M * 0.5, 1e9);
        w
    }

    fn view_from(eye: DVec3, target: DVec3) -> LodView {
        let v = Mat4::look_at_rh(Vec3::ZERO, (target - eye).as_vec3(), Vec3::Y);
        let p = Mat4::perspective_rh(60f32.to_radians(), 1.5, 1.0, 60_000.0);
        LodView { eye_m: eye, frustum: Frustum::from_view_proj(p * v), pixels_per_radian: 400.0 / (30f64.to_radians().tan()), target_px: 20.0, max_depth: BASE_DATA_DEPTH }
    }

    #[test]
    fn node_geometry_nests() {
        let r = NodeId::root(TileCoord::new(-1, 2));
        let k = r.children()[3].children()[0];
        assert_eq!(k.depth, 2);
        assert_eq!(k.size_m(), 1024.0);
        assert_eq!(k.spacing_m(), BASE_SPACING_M);
        assert_eq!(k.origin_m(), (-4096.0 + 2048.0, 8192.0 + 2048.0));
    }

    #[test]
    fn node_heights_are_the_tile_samples() {
        let w = world();
        let id = NodeId::root(TileCoord::new(0, 0)).children()[1].children()[2];
        let d = NodeData::from_world(id, &w).unwrap();
        // depth 2: one quad per sample; vertex (c, r) is global sample (64 + c, 32 + r).
        for (c, r) in [(0, 0), (5, 7), (32, 32), (-1, -1), (33, 10)] {
            assert_eq!(d.at(c, r), w.sample(64 + c as i64, 32 + r as i64).unwrap());
        }
        assert!(NodeData::from_world(NodeId { depth: 3, ..id }, &w).is_none(), "no base data below 32 m");
        assert!(d.min_m <= d.max_m && d.skirt_m >= 1.0);
    }

    #[test]
    fn skirts_cover_the_gap_to_any_coarser_neighbour() {
        // A depth-2 node and the depth-0 tile east of it share an edge line. Along it, the
        // fine polyline F and the coarse polyline C differ; whichever is higher must have a
        // skirt reaching below the other, at every point of the edge.
        let w = world();
        let fine = NodeData::from_world(NodeId { tile: TileCoord::new(0, 0), depth: 2, x: 3, y: 1 }, &w).unwrap();
        let coarse = NodeData::from_world(NodeId::root(TileCoord::new(1, 0)), &w).unwrap();
        let mut worst_gap = 0f32;
        for k in 0..=NODE_QUADS {
            // world z of fine vertex k on its east edge, as a position along the coarse west edge
            let z = 1024.0 + k as f64 * 32.0;
            let t = z / 128.0;
            let (c0, f) = (t.floor() as i32, (t - t.floor()) as f32);
            let c = if c0 >= NODE_QUADS as i32 { coarse.at(0, c0) } else { coarse.at(0, c0) * (1.0 - f) + coarse.at(0, c0 + 1) * f };
            let fh = fine.at(NODE_QUADS as i32, k as i32);
            let gap = (fh - c).abs();
            worst_gap = worst_gap.max(gap);
            if fh > c {
                assert!(fh - fine.skirt_m <= c, "crack at k={k}: fine {fh}, coarse {c}, skirt {}", fine.skirt_m);
            } else {
                assert!(c - coarse.skirt_m <= fh, "crack at k={k}: coarse {c}, fine {fh}, skirt {}", coarse.skirt_m);
            }
        }
        assert!(worst_gap > 0.5, "the levels must actually differ for this test to mean something ({worst_gap})");
    }

    #[test]
    fn selection_refines_near_the_eye_and_culls_behind_it() {
        let w = world();
        let mut cache = NodeCache::new();
        let tiles = w.drawable(TILE_SIZE_M * 0.5, TILE_SIZE_M * 0.5);
        let h = w.height_at(TILE_SIZE_M * 0.5, TILE_SIZE_M * 0.5).unwrap() as f64;
        let eye = DVec3::new(TILE_SIZE_M * 0.5, h + 200.0, TILE_SIZE_M * 0.5);
        let view = view_from(eye, eye + DVec3::new(1.0, -0.2, 0.0));
        let mut budget = usize::MAX;
        let nodes = cache.select(&tiles, &w, None, &view, &mut budget);
        assert!(nodes.iter().any(|n| n.id.depth == 2), "fine nodes near the eye");
        assert!(nodes.iter().any(|n| n.id.depth == 0), "coarse nodes far away");
        // Looking east: nothing drawn that lies entirely west of the eye (behind it).
        for n in &nodes {
            let (_, max) = n.bounds_m();
            assert!(max.x >= eye.x - 1.0, "{:?} is behind the camera", n.id);
        }
        // Coverage: the drawn nodes of one fully visible tile tile it exactly once.
        let east = TileCoord::new(1, 0);
        let area: f64 = nodes.iter().filter(|n| n.id.tile == east).map(|n| n.id.size_m().powi(2)).sum();
        assert!((area - TILE_SIZE_M * TILE_SIZE_M).abs() < 1.0, "area {area}");
        // With no build budget left, the cached nodes still draw and nothing new is built.
        let before = cache.built;
        let mut zero = 0;
        let again = cache.select(&tiles, &w, None, &view, &mut zero);
        assert_eq!(cache.built, before);
        assert_eq!(again.len(), nodes.len());
    }

    #[test]
    fn frustum_rejects_boxes_outside_and_keeps_boxes_inside() {
        let v = view_from(DVec3::ZERO, DVec3::new(0.0, 0.0, -1.0));
        assert!(v.frustum.intersects_box(Vec3::new(-1.0, -1.0, -20.0), Vec3::new(1.0, 1.0, -10.0)));
        assert!(!v.frustum.intersects_box(Vec3::new(-1.0, -1.0, 10.0), Vec3::new(1.0, 1.0, 20.0)));
        assert!(!v.frustum.intersects_box(Vec3::new(500.0, -1.0, -20.0), Vec3::new(600.0, 1.0, -10.0)));
        assert!(!v.frustum.intersects_box(Vec3::new(-1.0, -1.0, -70_000.0), Vec3::new(1.0, 1.0, -65_000.0)));
    }

    #[test]
    fn refined_nodes_read_the_patch_of_their_level_and_tile() {
        let node = NodeId { tile: TileCoord::new(-1, 0), depth: 5, x: 31, y: 0 };
        let p = node.patch().unwrap();
        assert_eq!((p.level, p.x, p.y), (2, -1, 0));
        assert_eq!(p.tile(), node.tile);
        assert!(NodeId { depth: 8, ..node }.patch().is_none());
        assert!(NodeId { depth: 2, x: 0, ..node }.patch().is_none());
    }

    /// Two neighbouring refined nodes made from different patches, in either order, share
    /// their edge exactly; the patches agree where their margins overlap; results do not
    /// depend on the order patches were made in.
    #[test]
    fn neighbouring_patches_and_nodes_agree() {
        let w = patch_world();
        let tem = scrambled();
        // Depth-4 nodes (level 1, 8 m) on both sides of a patch border (4 nodes per patch).
        let a = NodeId { tile: TileCoord::new(0, 0), depth: 4, x: 3, y: 5 };
        let b = NodeId { x: 4, ..a };
        let (ka, kb) = (a.patch().unwrap(), b.patch().unwrap());
        assert_ne!(ka, kb);
        let mut s1 = PatchStore::new(0, 0);
        s1.request(ka, 0.0);
        s1.request(kb, 1.0);
        for _ in 0..3 {
            run_all(&mut s1, &w, &tem);
            s1.request(ka, 0.0);
            s1.request(kb, 1.0);
        }
        let (na, nb) = (NodeData::from_patches(a, &s1, &w).unwrap(), NodeData::from_patches(b, &s1, &w).unwrap());
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
        let nb2 = NodeData::from_patches(b, &s2, &w).unwrap();
        let diff = nb.heights.iter().zip(&nb2.heights).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        assert!(diff < 1e-3, "order changed heights by {diff} m");
        // And the scrambled models did refine: not plain bicubic of the 32 m surface.
        let plain = TemSet::untrained(&Exec::cpu());
        let mut s3 = PatchStore::new(0, 0);
        for _ in 0..3 {
            s3.request(kb, 0.0);
            run_all(&mut s3, &w, &plain);
        }
        let nb3 = NodeData::from_patches(b, &s3, &w).unwrap();
        let moved = nb.heights.iter().zip(&nb3.heights).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        assert!(moved > 0.01, "the residual must change heights ({moved})");
    }

    /// An untrained ladder is exact bicubic (zero residual): every vertex of a refined 16 m
    /// node (apron included) equals the mean of the four bicubic ×2 pixels around its corner,
    /// computed independently from the 32 m samples with `Heightfield::upsample_bicubic`.
    #[test]
    fn untrained_refined_nodes_are_the_bicubic_surface() {
        let w = patch_world();
        let tem = TemSet::untrained(&Exec::cpu());
        let id = NodeId { tile: TileCoord::new(0, 0), depth: 3, x: 5, y: 2 };
        let mut s = PatchStore::new(0, 0);
        s.request(id.patch().unwrap(), 0.0);
        run_all(&mut s, &w, &tem);
        let d = NodeData::from_patches(id, &s, &w).unwrap();
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
        let w = patch_world();
        let tem = scrambled();
        let fine = NodeId { tile: TileCoord::new(0, 0), depth: 4, x: 3, y: 2 };
        let mid = NodeId { tile: TileCoord::new(0, 0), depth: 3, x: 2, y: 1 };
        let mut s = PatchStore::new(0, 0);
        for _ in 0..3 {
            s.request(fine.patch().unwrap(), 0.0);
            s.request(mid.patch().unwrap(), 0.0);
            run_all(&mut s, &w, &tem);
        }
        let f = NodeData::from_patches(fine, &s, &w).unwrap();
        let coarse_nodes = [NodeData::from_patches(mid, &s, &w).unwrap(), NodeData::from_world(NodeId { tile: TileCoord::new(0, 0), depth: 2, x: 1, y: 0 }, &w).unwrap()];
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
