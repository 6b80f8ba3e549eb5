//! Per-tile quadtree level of detail: node identities, the height data a node holds (base
//! samples now, refined heights from the TEM later), the node cache, and the selection of the
//! nodes to draw for a view (screen-space error + 3-D frustum culling).

use std::collections::HashMap;
use std::sync::Arc;

use glam::{DVec3, Mat4, Vec3, Vec4};

use super::coord::{TILE_SAMPLES, TILE_SIZE_M, TileCoord};
use super::refine::{PatchKey, PatchStore};
use super::stream::WorldStream;

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
}

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
        NodeData { id, heights, min_m, max_m, skirt_m, version: next_version() }
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
            let v = Vec3::new(
                if p.x >= 0.0 { max.x } else { min.x },
                if p.y >= 0.0 { max.y } else { min.y },
                if p.z >= 0.0 { max.z } else { min.z },
            );
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
        let d = if id.depth <= BASE_DATA_DEPTH { NodeData::from_world(id, world)? } else { refine?.node(id, world)? };
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
            if refining && let (Some(store), Some(key)) = (refine.as_deref_mut(), PatchKey::for_node(kids[0])) {
                store.request(key, distance_to_box(view.eye_m, min, max));
            }
        }
        out.push(d);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::coord::BASE_SPACING_M;
    use crate::world::noise::ProceduralSource;

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
}
