//! The numbers the overlay shows and the end-to-end test reads.

use crate::jobs::JobStats;

/// Numbers shown in the overlay and exported to the end-to-end test (all counts are totals
/// since the world was created unless stated).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct AppStats {
    /// Frames drawn.
    pub frames: u64,
    /// Tiles generated (dependencies included).
    pub tiles_generated: u64,
    /// Tiles in the cache now.
    pub tiles_cached: usize,
    /// Most tiles the cache may hold.
    pub tiles_capacity: usize,
    /// Wanted tiles still missing (or only standing in from an earlier world).
    pub tiles_pending: usize,
    /// Wanted tiles with nothing to draw yet, not even a stand-in of an earlier world.
    pub tiles_uncovered: usize,
    /// Wanted tiles standing in from an earlier world until this world's arrive (the
    /// surroundings of a sketch that changed, while the learned world grows around it again);
    /// cached ones beyond the wanted tiles are not counted (nothing draws them, and they are
    /// made again only when wanted).
    pub tiles_stale: usize,
    /// Tiles evicted.
    pub tiles_evicted: u64,
    /// Mean generation time per tile (milliseconds).
    pub ms_per_tile: f64,
    /// Quadtree nodes drawn in the last frame.
    pub nodes_drawn: usize,
    /// Of those, coarse stand-ins (the 128 m network tiles of learned tiles not made yet).
    pub coarse_drawn: usize,
    /// Of those, the far field's (128 m network tiles beyond the detailed ones).
    pub far_drawn: usize,
    /// The far field's tiles around the eye that have not arrived yet.
    pub far_pending: usize,
    /// Quadtree nodes cached.
    pub nodes_cached: usize,
    /// Deepest quadtree depth drawn in the last frame.
    pub max_depth_drawn: u8,
    /// The last frame drew the previous world's picture: the world shown changed and has not
    /// yet made the tiles near the eye.
    pub previous_world_shown: bool,
    /// Most nodes a frame may draw on this device (`None`: no GPU limit known).
    pub node_budget: Option<usize>,
    /// The LOD target the view is selected with (px): the user's, or coarser while the
    /// view would exceed the node budget.
    pub lod_px_effective: f64,
    /// Refined patches (TEM quads) made since the world was created.
    pub quads_made: u64,
    /// Mean TEM inference time per quad (milliseconds, read-back included).
    pub ms_per_quad: f64,
    /// Refined patches cached.
    pub patches_cached: usize,
    /// Where the TEM runs ("" while it is off).
    pub refine_backend: String,
    /// Median frame time over the recent window (milliseconds).
    pub frame_ms_median: f64,
    /// Worst frame time over the recent window (milliseconds).
    pub frame_ms_worst: f64,
    /// Eye position (world metres).
    pub eye_m: [f64; 3],
    /// Milliseconds the last frame spent making tiles (world update).
    pub world_ms: f64,
    /// Milliseconds the last frame spent selecting and building quadtree nodes.
    pub nodes_ms: f64,
    /// The world's generator ("learned" or "procedural").
    pub source: String,
    /// The learned world's tile jobs (started, done, failed, stale, in flight).
    pub tile_jobs: JobStats,
    /// Order-independent hash (hex) of the contents and coordinates of the tiles drawn: equal
    /// on two pages exactly when they show bit-identical tiles.
    pub view_checksum: String,
    /// The sketch canvas's revision (changes with every stroke).
    pub sketch_revision: u64,
    /// The canvas revision whose terrain the sketch world shows (0: none yet).
    pub sketch_shown: u64,
    /// Milliseconds the last sketch took to become terrain (the generator's own time).
    pub sketch_ms: f64,
    /// The sketch world's generator jobs.
    pub sketch_jobs: JobStats,
}
