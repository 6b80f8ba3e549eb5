//! The infinite world: tile grid, the order-independent tile schedule, tile sources
//! (procedural, learned, sketched), streaming with a bounded cache, and the per-tile quadtree
//! of level-of-detail nodes. Data flows seed → tile → quadtree node; nothing here knows about
//! rendering.

pub mod drainage;
pub mod erosion;
pub mod export;
pub mod learned;
pub mod noise;
pub mod pins;
pub mod quadtree;
pub mod ranges;
pub mod refine;
pub mod seam;
pub mod sketched;
pub mod stream;
pub mod tile;

pub use crate::grid::{BASE_SPACING_M, TILE_SAMPLES, TILE_SIZE_M, TileCoord};
pub use noise::{NoiseKind, NoiseParams, ProceduralSource};
pub use quadtree::{LodView, NodeCache, NodeData, NodeId};
pub use refine::{PatchKey, PatchStore, RefineJob, RefineStats};
pub use stream::{StreamStats, WorldStream};
pub use tile::{Neighbourhood, SourceKind, Tile, TileSource};
