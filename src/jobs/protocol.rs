//! The typed protocol between the page's core and whoever runs its models: the CPU worker
//! (a Web Worker in the page, a thread natively), the main thread when there is no worker,
//! and the GPU. One [`Request`] enum, one [`Reply`] enum, each wrapped with the request's id
//! and the world epoch it was made for, and encoded with serde (postcard: compact binary, so a
//! heights array crosses as its bytes, not as text, and a wrong or truncated message is a
//! decoding error, never a trap).

use serde::{Deserialize, Serialize};

use crate::grid::TileCoord;
use crate::sketch::Sketch;
use crate::world::NoiseParams;
use crate::world::learned::{NetworkWork, WorkKeys};

/// What the core asks of a model runner.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Request {
    /// Load the TEM from its weight files (burnpack bytes, level order).
    LoadTem {
        /// One file per level.
        files: Vec<Vec<u8>>,
    },
    /// Load the learned world's networks (TCM and ×4 step, burnpack bytes).
    LoadWorld {
        /// The tile-completion network's file.
        tcm: Vec<u8>,
        /// The ×4 step's file.
        grow: Vec<u8>,
    },
    /// Load the sketch models (generator and VAE, burnpack bytes).
    LoadSketch {
        /// The sketch → terrain generator's file.
        generator: Vec<u8>,
        /// The VAE's file.
        vae: Vec<u8>,
    },
    /// Make tile `tile` of world `seed`: procedural with `noise`, else learned.
    Tile {
        /// The world's seed.
        seed: u64,
        /// Which tile.
        tile: TileCoord,
        /// The procedural world's noise; `None` for the learned world.
        noise: Option<NoiseParams>,
    },
    /// Run TEM level `level` on `n` windows of `side`² heights (metres), concatenated.
    Enhance {
        /// TEM level (0 = 32 → 16 m).
        level: u8,
        /// Number of windows.
        n: u32,
        /// Side of a window (pixels).
        side: u32,
        /// The windows' heights, row-major, one after the other.
        input: Vec<f32>,
    },
    /// Turn a sketch into terrain.
    Sketch {
        /// Its extent (metres across), which the generator is told.
        extent_m: f64,
        /// The sketch (last: its bytes end the message).
        sketch: SketchBytes,
    },
    /// Propose `n` sketches near `sketch` (seeded), each with its terrain.
    Variants {
        /// The sketch to vary.
        sketch: SketchBytes,
        /// How many (1 ..= 16).
        n: u32,
        /// The proposals' seed.
        seed: u64,
    },
    /// The sketch α·a + (1 − α)·b in the VAE's code space, with its terrain.
    Blend {
        /// The first sketch.
        a: SketchBytes,
        /// The second sketch.
        b: SketchBytes,
        /// The weight of `a`, 0 ..= 1.
        alpha: f32,
    },
    /// Pin these 32 m tiles ([`crate::grid::TILE_SAMPLES`]² heights each, metres) into the
    /// learned world, replacing any pins before ([`crate::world::pins`]); the reply names them
    /// by their hash.
    Pin {
        /// The pinned tiles and their heights.
        tiles: Vec<(TileCoord, Vec<f32>)>,
        /// Tiles set in as they are, the world made without them (pins with a soft edge:
        /// [`crate::world::learned::LearnedSource::with_pins_set_in`]), and their heights.
        set_in: Vec<(TileCoord, Vec<f32>)>,
    },
    /// Tile `tile` of learned world `seed` as it is without any pins
    /// ([`crate::grid::TILE_SAMPLES`]² heights, metres): the ground a small sketch is set into
    /// ([`crate::world::sketched::SketchSource::with_base`]).
    UnpinnedTile {
        /// The world's seed.
        seed: u64,
        /// Which tile.
        tile: TileCoord,
    },
    /// The next batch of network work that tile `tile` of learned world `seed` needs
    /// ([`crate::world::learned::LearnedSource::network_work`]; with `coarse`, its 128 m tile
    /// of [`Request::Coarse`]: [`crate::world::learned::LearnedSource::coarse_work`]): the CPU
    /// worker answers [`Reply::Work`], to be run elsewhere ([`Request::RunWork`]) and handed
    /// back ([`Request::AcceptWork`]).
    WorldWork {
        /// The world's seed.
        seed: u64,
        /// Which tile.
        tile: TileCoord,
        /// The work of its eroded 128 m tile (the far field's), not of its 32 m tile.
        coarse: bool,
    },
    /// Run a batch of the learned world's network work (on the GPU in one call, or on the CPU
    /// kernels): [`Reply::Outputs`], one per item.
    RunWork {
        /// The batch.
        work: NetworkWork,
        /// On the GPU, run a ×4 step's batch in two halves with a wait for the device between
        /// them ([`crate::world::learned::NetworksOn::run`]: a page draws a frame between the
        /// halves); the same outputs either way. The CPU kernels ignore it.
        halves: bool,
    },
    /// Keep the outputs of a batch run elsewhere in the learned world of `seed`
    /// ([`crate::world::learned::LearnedSource::accept`]): [`Reply::Accepted`].
    AcceptWork {
        /// The world's seed.
        seed: u64,
        /// The batch's network and tiles.
        keys: WorkKeys,
        /// One output per tile, as [`Reply::Outputs`] gave them.
        outputs: Vec<Vec<f32>>,
        /// Milliseconds the batch took where it ran.
        ms: f64,
    },
    /// The 128 m network tile `tile` of learned world `seed` ([`crate::models::tcm::TILE_PX`]²
    /// heights, metres, joined to its schedule's neighbours): cheap, so the view draws it while
    /// the 32 m tile is made.
    Coarse {
        /// The world's seed.
        seed: u64,
        /// Which tile.
        tile: TileCoord,
    },
}

impl Request {
    /// [`Request::Pin`] of `pins`' 32 m tiles (none: the pins cleared).
    pub fn pin(pins: &crate::world::pins::Pins) -> Self {
        let (hard, set_in) = pins.split_soft();
        Request::Pin { tiles: hard.iter().map(|(c, t)| (c, t.fine.to_vec())).collect(), set_in: set_in.into_iter().map(|(c, t)| (c, t.to_vec())).collect() }
    }

    /// Whether the request belongs to a world (a tile, a TEM batch): its epoch is checked, and
    /// it is dropped unmade once a newer world's request has arrived.
    pub fn of_world(&self) -> bool {
        matches!(self, Request::Tile { .. } | Request::Enhance { .. } | Request::Coarse { .. } | Request::WorldWork { .. } | Request::RunWork { .. })
    }

    /// A short name for messages ("tile", "enhance", …).
    pub fn kind(&self) -> &'static str {
        match self {
            Request::LoadTem { .. } => "load-tem",
            Request::LoadWorld { .. } => "load-world",
            Request::LoadSketch { .. } => "load-sketch",
            Request::Tile { .. } => "tile",
            Request::Enhance { .. } => "enhance",
            Request::Sketch { .. } => "sketch",
            Request::Variants { .. } => "variants",
            Request::Blend { .. } => "blend",
            Request::Coarse { .. } => "coarse",
            Request::Pin { .. } => "pin",
            Request::UnpinnedTile { .. } => "unpinned-tile",
            Request::WorldWork { .. } => "world-work",
            Request::RunWork { .. } => "run-work",
            Request::AcceptWork { .. } => "accept-work",
        }
    }
}

/// A request on the wire: its id (the reply carries it back), the world epoch it was made
/// for, and how long the runner may rest per millisecond of work between pieces of a tile or
/// TEM batch (0: all in one go; see [`crate::models::runtime::worker_rest_per_work`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// The request's id (never 0; 0 names the runner itself in a reply).
    pub id: u32,
    /// The world epoch it was made for ([`crate::jobs::JobQueue::epoch`]).
    pub epoch: u64,
    /// Rest (ms) per ms of work between pieces.
    pub rest_per_work: f64,
    /// What is asked.
    pub request: Request,
}

/// What a runner answers.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Reply {
    /// The models loaded; the short hash of their weight files.
    Loaded {
        /// [`crate::models::weights_hash`] of the files.
        hash: String,
    },
    /// Heights (metres for tiles and the TEM, the 0–255 scale for a sketch's terrain) and the
    /// milliseconds of work they took on the runner's clock.
    Heights {
        /// The heights, row-major.
        heights: Vec<f32>,
        /// Milliseconds of work (rests not counted).
        ms: f64,
    },
    /// Sketches (variants, a blend) and their terrains (concatenated, 256² each).
    Sketches {
        /// The sketches.
        sketches: Vec<SketchBytes>,
        /// Their terrains, one after the other.
        heights: Vec<f32>,
        /// Milliseconds of work.
        ms: f64,
    },
    /// The next batch of network work a learned tile needs ([`Request::WorldWork`]).
    Work(NetworkWork),
    /// A batch's outputs, one per item ([`Request::RunWork`]), and the milliseconds it took.
    Outputs {
        /// The outputs, in the batch's order.
        outputs: Vec<Vec<f32>>,
        /// Milliseconds of work.
        ms: f64,
    },
    /// A batch's outputs were kept ([`Request::AcceptWork`]).
    Accepted,
    /// A newer world's request arrived before this one was made: it was dropped unmade.
    Stale,
    /// The request could not be answered (a broken weight file, a malformed request, models
    /// not loaded): why.
    Failed(String),
}

/// A reply on the wire: the id of the request it answers (0: about the runner itself, e.g. it
/// could not start) and the reply.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Answer {
    /// The request's id.
    pub id: u32,
    /// The reply.
    pub reply: Reply,
}

/// Why bytes are not a message of this protocol.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("malformed {what} ({why})")]
pub struct Malformed {
    what: &'static str,
    why: String,
}

impl Envelope {
    /// The bytes that cross to the runner.
    pub fn encode(&self) -> Vec<u8> {
        postcard::to_stdvec(self).expect("a request always encodes")
    }

    /// Reads a request. On failure, also the id when the bytes start with one (so the error
    /// reply still reaches whoever asked).
    pub fn decode(bytes: &[u8]) -> Result<Self, (Option<u32>, Malformed)> {
        postcard::from_bytes(bytes).map_err(|e| {
            let id = postcard::take_from_bytes::<u32>(bytes).ok().map(|(id, _)| id);
            (id, Malformed { what: "request", why: e.to_string() })
        })
    }
}

impl Answer {
    /// The bytes that cross back.
    pub fn encode(&self) -> Vec<u8> {
        postcard::to_stdvec(self).expect("a reply always encodes")
    }

    /// The id of the reply in `bytes`, read without decoding the rest.
    pub fn peek_id(bytes: &[u8]) -> Option<u32> {
        postcard::take_from_bytes::<u32>(bytes).ok().map(|(id, _)| id)
    }

    /// Reads a reply.
    pub fn decode(bytes: &[u8]) -> Result<Self, Malformed> {
        postcard::from_bytes(bytes).map_err(|e| Malformed { what: "reply", why: e.to_string() })
    }
}

/// A sketch on the wire: one byte per pixel, band | ridge << 2 | valley << 3
/// ([`Sketch::packed`]), read back and checked by whoever uses it ([`SketchBytes::sketch`]).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SketchBytes(pub Vec<u8>);

impl From<&Sketch> for SketchBytes {
    fn from(s: &Sketch) -> Self {
        Self(s.packed())
    }
}

impl SketchBytes {
    /// The sketch, or why these bytes are not one.
    pub fn sketch(&self) -> Result<Sketch, crate::sketch::SketchError> {
        Sketch::from_packed(&self.0)
    }
}
