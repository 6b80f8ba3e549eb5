//! The one procedure that answers every [`Request`] of the protocol on the CPU: the models a
//! runner keeps (loaded from weight bytes) and what it does with each request. The page's Web
//! Worker, the main thread when the browser gives no worker, a native thread
//! ([`super::native`]) and the tests all run this code.
//!
//! Learned tiles and TEM batches are answered in pieces ([`Task`]): one network tile, one
//! ×4 step, one drainage block or one TEM window at a time, so a runner beside a software
//! rasteriser can rest between pieces ([`Envelope::rest_per_work`]). Every request of a world
//! carries its epoch: once a newer world's request has arrived, older ones still queued or
//! half made are dropped with [`Reply::Stale`] instead of being finished for nobody.

use std::sync::Arc;

use super::protocol::{Answer, Envelope, Reply, Request, SketchBytes};
use crate::grid::TileCoord;
use crate::models::sketch_vae::SketchModels;
use crate::models::tem::{Exec, LEVELS, TemSet};
use crate::models::weights_hash;
use crate::sketch::{SKETCH_PX, Sketch};
use crate::world::learned::{LearnedModels, LearnedSource};
use crate::world::{Neighbourhood, ProceduralSource, TileSource};

/// Most variants one request may ask for.
pub const MAX_VARIANTS: u32 = 16;

/// The models a runner has loaded, and the newest world epoch it has seen.
pub struct Runner {
    tem: Option<TemSet>,
    world: Option<LearnedSource>,
    /// The learned world without pins, once asked for ([`Request::UnpinnedTile`]).
    unpinned: Option<LearnedSource>,
    sketch: Option<SketchModels>,
    epoch: u64,
    threads: usize,
}

/// A learned tile or TEM batch being made piece by piece ([`Runner::step`]).
pub struct Task {
    /// The request's id.
    pub id: u32,
    /// Rest (ms) per ms of work the caller may take between pieces.
    pub rest_per_work: f64,
    epoch: u64,
    work: Work,
    /// Milliseconds of work so far.
    ms: f64,
}

enum Work {
    Tile { seed: u64, tile: TileCoord },
    Enhance { level: usize, side: usize, windows: Vec<Vec<f32>>, out: Vec<f32> },
}

/// How a runner takes a request: answered at once, or a task to make in pieces.
pub enum Accepted {
    /// The answer.
    Now(Answer),
    /// Call [`Runner::step`] until it answers.
    Paced(Task),
}

impl Runner {
    /// A runner with no models loaded, whose kernels use `threads` threads.
    pub fn new(threads: usize) -> Self {
        Self { tem: None, world: None, unpinned: None, sketch: None, epoch: 0, threads: threads.max(1) }
    }

    /// Reads a request from its bytes and takes it; malformed bytes are answered with
    /// [`Reply::Failed`] (to the id they start with, else 0).
    pub fn accept_bytes(&mut self, bytes: &[u8]) -> Accepted {
        match Envelope::decode(bytes) {
            Ok(env) => self.accept(env),
            Err((id, e)) => Accepted::Now(Answer { id: id.unwrap_or(0), reply: Reply::Failed(e.to_string()) }),
        }
    }

    /// Takes a request: loads and sketch work are answered now; tiles and TEM batches become
    /// a [`Task`] (a procedural tile is one piece). A world request older than the newest
    /// seen is answered [`Reply::Stale`].
    pub fn accept(&mut self, env: Envelope) -> Accepted {
        let id = env.id;
        let now = |reply| Accepted::Now(Answer { id, reply });
        if env.request.of_world() {
            if env.epoch < self.epoch {
                return now(Reply::Stale);
            }
            self.epoch = env.epoch;
        }
        let task = |work| Accepted::Paced(Task { id, rest_per_work: env.rest_per_work.max(0.0), epoch: env.epoch, work, ms: 0.0 });
        match env.request {
            Request::Tile { seed, tile, noise: None } => task(Work::Tile { seed, tile }),
            Request::Enhance { level, n, side, input } => match enhance_windows(level, n, side, input) {
                Ok(windows) => task(Work::Enhance { level: level as usize, side: side as usize, windows, out: Vec::new() }),
                Err(e) => now(Reply::Failed(e)),
            },
            request => {
                let (reply, ms) = timed(|| self.answer(request));
                now(match reply {
                    Ok(Reply::Heights { heights, .. }) => Reply::Heights { heights, ms },
                    Ok(Reply::Sketches { sketches, heights, .. }) => Reply::Sketches { sketches, heights, ms },
                    Ok(r) => r,
                    Err(e) => Reply::Failed(e),
                })
            }
        }
    }

    /// Does one piece of `task`: returns its answer once made (or [`Reply::Stale`] when a
    /// newer world's request arrived meanwhile), and the milliseconds this piece took.
    pub fn step(&mut self, task: &mut Task) -> (Option<Answer>, f64) {
        let answer = |reply| Some(Answer { id: task.id, reply });
        if task.epoch < self.epoch {
            return (answer(Reply::Stale), 0.0);
        }
        let (out, ms) = timed(|| -> Result<Option<Vec<f32>>, String> {
            match &mut task.work {
                Work::Tile { seed, tile } => {
                    let world = self.world.as_ref().ok_or(NO_WORLD.to_string())?;
                    if world.prepare(*seed, *tile) {
                        return Ok(None);
                    }
                    Ok(Some(world.generate(*seed, *tile, &Neighbourhood::default()).heights))
                }
                Work::Enhance { level, side, windows, out } => {
                    let tem = self.tem.as_ref().ok_or("the CPU worker has no TEM loaded".to_string())?;
                    let window = windows.remove(0);
                    out.extend(tem.enhance_blocking(*level, window, 1, *side)?);
                    Ok(windows.is_empty().then(|| std::mem::take(out)))
                }
            }
        });
        task.ms += ms;
        let reply = match out {
            Ok(None) => return (None, ms),
            Ok(Some(heights)) => Reply::Heights { heights, ms: task.ms },
            Err(e) => Reply::Failed(e),
        };
        (answer(reply), ms)
    }

    /// Answers a request completely, all pieces at once (the native runner and tests).
    pub fn handle(&mut self, env: Envelope) -> Answer {
        let accepted = self.accept(env);
        self.finish(accepted)
    }

    /// Answers a request taken by [`Runner::accept`] or [`Runner::accept_bytes`] completely,
    /// all its pieces at once.
    pub fn finish(&mut self, accepted: Accepted) -> Answer {
        match accepted {
            Accepted::Now(a) => a,
            Accepted::Paced(mut task) => loop {
                if let (Some(a), _) = self.step(&mut task) {
                    break a;
                }
            },
        }
    }

    /// Loads the TEM from `files` and runs level 0 on the probe window `reps` times on this
    /// thread: each run's milliseconds and the last run's heights (the kernels' own speed
    /// where the runner is, e.g. the page's main thread).
    pub fn time_tem(&mut self, files: Vec<Vec<u8>>, reps: usize) -> Result<(Vec<f64>, Vec<f32>), String> {
        let epoch = self.epoch;
        let env = |request| Envelope { id: 1, epoch, rest_per_work: 0.0, request };
        if let Reply::Failed(e) = self.handle(env(Request::LoadTem { files })).reply {
            return Err(e);
        }
        let (mut ms, mut out) = (Vec::new(), Vec::new());
        for _ in 0..reps {
            let input = crate::models::tem::probe_input(0);
            match self.handle(env(Request::Enhance { level: 0, n: 1, side: crate::models::tem::PROBE_SIDE as u32, input })).reply {
                Reply::Heights { heights, ms: t } => (ms.push(t), out = heights),
                other => return Err(format!("{other:?}")),
            };
        }
        Ok((ms, out))
    }

    /// The newest world epoch this runner has seen.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    fn answer(&mut self, request: Request) -> Result<Reply, String> {
        match request {
            Request::LoadTem { files } => {
                let hash = weights_hash(&files.iter().map(Vec::as_slice).collect::<Vec<_>>());
                self.tem = Some(TemSet::from_bytes(files, &Exec::Cpu { threads: self.threads }).map_err(|e| e.to_string())?);
                Ok(Reply::Loaded { hash })
            }
            Request::LoadWorld { tcm, grow } => {
                let models = LearnedModels::from_bytes(&tcm, &grow).map_err(|e| e.to_string())?;
                let hash = models.hash.clone();
                self.world = Some(LearnedSource::new(Arc::new(models), self.threads));
                self.unpinned = None;
                Ok(Reply::Loaded { hash })
            }
            Request::LoadSketch { generator, vae } => {
                let models = SketchModels::from_bytes(&generator, &vae).map_err(|e| e.to_string())?;
                let hash = models.hash.clone();
                self.sketch = Some(models);
                Ok(Reply::Loaded { hash })
            }
            Request::Tile { seed, tile, noise: Some(noise) } => {
                Ok(Reply::Heights { heights: ProceduralSource::new(noise).generate(seed, tile, &Neighbourhood::default()).heights, ms: 0.0 })
            }
            Request::Pin { tiles, set_in } => {
                let world = self.world.as_ref().ok_or(NO_WORLD.to_string())?;
                let mut pins = crate::world::pins::Pins::new();
                for (c, heights) in tiles {
                    pins.insert(c, heights).map_err(|e| format!("tile {}, {}: {e}", c.i, c.j))?;
                }
                let mut set = Vec::new();
                for (c, heights) in set_in {
                    // Checked as a pin's heights are.
                    let tile = crate::world::pins::PinnedTile::new(heights).map_err(|e| format!("tile {}, {}: {e}", c.i, c.j))?;
                    set.push((c, tile.fine));
                }
                let hash = pins.hash();
                self.world = Some(world.with_pins_set_in(pins, set));
                Ok(Reply::Loaded { hash })
            }
            Request::UnpinnedTile { seed, tile } => {
                let world = self.world.as_ref().ok_or(NO_WORLD.to_string())?;
                let free = self.unpinned.get_or_insert_with(|| world.with_pins(crate::world::pins::Pins::new()));
                Ok(Reply::Heights { heights: free.generate(seed, tile, &Neighbourhood::default()).heights, ms: 0.0 })
            }
            Request::Coarse { seed, tile } => {
                let world = self.world.as_ref().ok_or(NO_WORLD.to_string())?;
                Ok(Reply::Heights { heights: world.eroded_tile(seed, tile).to_vec(), ms: 0.0 })
            }
            Request::Sketch { sketch: s, extent_m } => {
                let s = sketch_of(&s)?;
                let m = self.sketch.as_ref().ok_or(NO_SKETCH)?;
                Ok(Reply::Heights { heights: m.generator.generate(&s, extent_m, &mut Default::default(), self.threads), ms: 0.0 })
            }
            Request::Variants { sketch: s, n, seed } => {
                if !(1..=MAX_VARIANTS).contains(&n) {
                    return Err(format!("a request asks for 1 to {MAX_VARIANTS} variants, not {n}"));
                }
                let s = sketch_of(&s)?;
                let m = self.sketch.as_ref().ok_or(NO_SKETCH)?;
                let list = m.vae.variants(&s, n as usize, seed, &mut Default::default(), self.threads);
                Ok(self.terrains(list))
            }
            Request::Blend { a, b, alpha } => {
                if !(0.0..=1.0).contains(&alpha) {
                    return Err(format!("a blend's alpha is in 0..1, not {alpha}"));
                }
                let (a, b) = (sketch_of(&a)?, sketch_of(&b)?);
                let m = self.sketch.as_ref().ok_or(NO_SKETCH)?;
                let s = m.vae.interpolate(&a, &b, alpha, &mut Default::default(), self.threads);
                Ok(self.terrains(vec![s]))
            }
            Request::WorldWork { seed, tile, coarse } => {
                let world = self.world.as_ref().ok_or(NO_WORLD.to_string())?;
                Ok(Reply::Work(if coarse { world.coarse_work(seed, tile) } else { world.network_work(seed, tile) }))
            }
            Request::RunWork { work, .. } => {
                let world = self.world.as_ref().ok_or(NO_WORLD.to_string())?;
                work.check()?;
                let t0 = web_time::Instant::now();
                let outputs = world.models().run_work(&work, &mut Default::default(), self.threads)?;
                Ok(Reply::Outputs { outputs, ms: t0.elapsed().as_secs_f64() * 1e3 })
            }
            Request::AcceptWork { seed, keys, outputs, ms } => {
                let world = self.world.as_ref().ok_or(NO_WORLD.to_string())?;
                world.accept(seed, &keys, outputs, ms)?;
                Ok(Reply::Accepted)
            }
            Request::Tile { .. } | Request::Enhance { .. } => unreachable!("tiles and TEM batches are tasks"),
        }
    }

    /// `sketches` with their terrains.
    fn terrains(&self, sketches: Vec<Sketch>) -> Reply {
        let g = &self.sketch.as_ref().expect("checked by the caller").generator;
        let heights = sketches.iter().flat_map(|s| g.generate(s, crate::world::sketched::SKETCH_EXTENT_M, &mut Default::default(), self.threads)).collect();
        Reply::Sketches { sketches: sketches.iter().map(SketchBytes::from).collect(), heights, ms: 0.0 }
    }
}

/// The sketch of a request, or why its bytes are not one.
fn sketch_of(s: &SketchBytes) -> Result<Sketch, String> {
    s.sketch().map_err(|e| format!("the request's sketch is broken ({e})"))
}

const NO_WORLD: &str = "the CPU worker has no learned world loaded";
const NO_SKETCH: &str = "the CPU worker has no sketch models loaded";

/// The windows of a TEM request, checked: a level of the ladder, at least one window, and
/// exactly `n`·`side`² heights.
fn enhance_windows(level: u8, n: u32, side: u32, input: Vec<f32>) -> Result<Vec<Vec<f32>>, String> {
    let (n, side) = (n as usize, side as usize);
    if level as usize >= LEVELS {
        return Err(format!("no TEM level {level} (there are {LEVELS})"));
    }
    if n == 0 || side == 0 || side > 4096 || input.len() != n * side * side {
        return Err(format!("a TEM request of {n} windows of {side}² needs {} heights, not {}", n * side * side, input.len()));
    }
    Ok(input.chunks(side * side).map(<[f32]>::to_vec).collect())
}

/// A runner and the tasks it makes in pieces, oldest first: what a worker keeps between
/// messages. [`Queue::accept_bytes`] takes a request; while tasks wait, the worker's loop
/// makes them with [`Queue::next_piece`], resting between pieces as each request asks.
pub struct Queue {
    /// The runner.
    pub runner: Runner,
    tasks: std::collections::VecDeque<Task>,
    /// Whether a loop is making the tasks (it runs until none is left).
    looping: bool,
}

impl Queue {
    /// An empty queue whose runner's kernels use `threads` threads.
    pub fn new(threads: usize) -> Self {
        Self { runner: Runner::new(threads), tasks: Default::default(), looping: false }
    }

    /// Takes a request's bytes: its answer if it is answered now, and whether the caller must
    /// start the loop of [`Queue::next_piece`] (a task joined and no loop runs).
    pub fn accept_bytes(&mut self, bytes: &[u8]) -> (Option<Answer>, bool) {
        match self.runner.accept_bytes(bytes) {
            Accepted::Now(a) => (Some(a), false),
            Accepted::Paced(t) => {
                self.tasks.push_back(t);
                (None, !std::mem::replace(&mut self.looping, true))
            }
        }
    }

    /// Makes one piece of the oldest task: the answer when that ends it, and the rest (ms) to
    /// take before the next piece (none after a task's last piece). `None` when no task is
    /// left: the loop ends (the next task starts a new one).
    pub fn next_piece(&mut self) -> Option<(Option<Answer>, f64)> {
        let Some(task) = self.tasks.front_mut() else {
            self.looping = false;
            return None;
        };
        let (answer, ms) = self.runner.step(task);
        let rest = ms * task.rest_per_work;
        if answer.is_some() {
            self.tasks.pop_front();
            return Some((answer, 0.0));
        }
        Some((None, rest))
    }
}

/// `f`'s result and how long it took (milliseconds).
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64) {
    let t0 = web_time::Instant::now();
    let out = f();
    (out, t0.elapsed().as_secs_f64() * 1000.0)
}

/// Terrain made from a sketch is 256² heights; a reply of sketches carries that many per sketch.
pub const SKETCH_TERRAIN: usize = SKETCH_PX * SKETCH_PX;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::jobs::native::NativeRunner;
    use crate::models::tem::{PROBE_SIDE, probe_input, weight_file};
    use crate::world::NoiseParams;

    fn weight(name: &str) -> Vec<u8> {
        std::fs::read(crate::repo_root().join("weights").join(name)).unwrap()
    }

    fn env(id: u32, epoch: u64, request: Request) -> Envelope {
        Envelope { id, epoch, rest_per_work: 0.0, request }
    }

    fn heights(a: Answer) -> Vec<f32> {
        match a.reply {
            Reply::Heights { heights, ms } => {
                assert!(ms >= 0.0);
                heights
            }
            other => panic!("expected heights, got {other:?}"),
        }
    }

    fn failed(a: &Answer) -> &str {
        match &a.reply {
            Reply::Failed(why) => why,
            other => panic!("expected an error reply, got {other:?}"),
        }
    }

    /// Every request kind, as bytes through the native runner thread, gives bit-identical
    /// results to calling the models directly: TEM, a learned coarse stand-in (the 128 m
    /// network tile), learned and procedural tiles (pinned, set in, and the world's own tile
    /// without the pins), a sketch's terrain, 2 variants (2 sketches, 2·256² heights) and a
    /// blend; the loads answer the weights' hashes.
    #[test]
    fn every_request_kind_through_the_runner_thread_matches_the_models_called_directly() {
        let r = NativeRunner::spawn(1);
        let tem_files: Vec<Vec<u8>> = (0..LEVELS).map(|k| weight(&weight_file(k))).collect();
        let (tcm, grow) = (weight(crate::world::learned::TCM_FILE), weight(crate::world::learned::GROW_FILE));
        let (generator, vae) = (weight(crate::models::sketch::WEIGHT_FILE), weight(crate::models::sketch_vae::WEIGHT_FILE));
        let loads = [
            Request::LoadTem { files: tem_files.clone() },
            Request::LoadWorld { tcm: tcm.clone(), grow: grow.clone() },
            Request::LoadSketch { generator: generator.clone(), vae: vae.clone() },
        ];
        let hashes: Vec<String> = loads
            .into_iter()
            .enumerate()
            .map(|(k, l)| match r.call(&env(k as u32 + 1, 0, l)).unwrap() {
                Answer { id, reply: Reply::Loaded { hash } } if id == k as u32 + 1 => hash,
                other => panic!("load {k}: {other:?}"),
            })
            .collect();
        let models = LearnedModels::from_bytes(&tcm, &grow).unwrap();
        assert_eq!(hashes[1], models.hash);
        let sketch_models = SketchModels::from_bytes(&generator, &vae).unwrap();
        assert_eq!(hashes[2], sketch_models.hash);
        assert_eq!(hashes[0].len(), 8);

        let tem = TemSet::from_bytes(tem_files, &Exec::Cpu { threads: 1 }).unwrap();
        let input = probe_input(1);
        let want = tem.enhance_blocking(1, input.clone(), 1, PROBE_SIDE).unwrap();
        let got = heights(r.call(&env(10, 0, Request::Enhance { level: 1, n: 1, side: PROBE_SIDE as u32, input })).unwrap());
        assert_eq!(got, want);

        let c = TileCoord::new(1, -1);
        let learned = LearnedSource::new(Arc::new(models), 1);
        let want = learned.eroded_tile(42, c.offset(1, 0)).to_vec();
        assert_eq!(want.len(), crate::world::stream::COARSE_SAMPLES.pow(2));
        assert_eq!(heights(r.call(&env(16, 0, Request::Coarse { seed: 42, tile: c.offset(1, 0) })).unwrap()), want);
        let want = learned.generate(42, c, &Neighbourhood::default()).heights;
        assert_eq!(heights(r.call(&env(11, 0, Request::Tile { seed: 42, tile: c, noise: None })).unwrap()), want);
        // Pinned tiles: the reply names the pins, and the pinned tile comes back as pinned.
        let free_tile = want.clone();
        let pin: Vec<f32> = (0..crate::grid::TILE_SAMPLES.pow(2)).map(|p| 700.0 + (p % 97) as f32).collect();
        let mut pins = crate::world::pins::Pins::new();
        pins.insert(c, pin.clone()).unwrap();
        match r.call(&env(17, 0, Request::Pin { tiles: vec![(c, pin.clone())], set_in: vec![] })).unwrap().reply {
            Reply::Loaded { hash } => assert_eq!(hash, pins.hash()),
            other => panic!("pin: {other:?}"),
        }
        assert_eq!(heights(r.call(&env(18, 0, Request::Tile { seed: 42, tile: c, noise: None })).unwrap()), pin);
        let beside = learned.with_pins(pins).generate(42, c.offset(1, 0), &Neighbourhood::default()).heights;
        assert_eq!(heights(r.call(&env(19, 0, Request::Tile { seed: 42, tile: c.offset(1, 0), noise: None })).unwrap()), beside);
        // With pins, the world's own tile without them.
        assert_eq!(heights(r.call(&env(22, 0, Request::UnpinnedTile { seed: 42, tile: c })).unwrap()), free_tile);
        // A tile set in: it comes back as it is, and the tile beside it is the world's own.
        match r.call(&env(23, 0, Request::Pin { tiles: vec![], set_in: vec![(c, pin.clone())] })).unwrap().reply {
            Reply::Loaded { hash } => assert_eq!(hash, ""),
            other => panic!("set in: {other:?}"),
        }
        assert_eq!(heights(r.call(&env(24, 0, Request::Tile { seed: 42, tile: c, noise: None })).unwrap()), pin);
        let own = learned.generate(42, c.offset(1, 0), &Neighbourhood::default()).heights;
        assert_eq!(heights(r.call(&env(25, 0, Request::Tile { seed: 42, tile: c.offset(1, 0), noise: None })).unwrap()), own);
        // No pins: the world without them again.
        match r.call(&env(20, 0, Request::Pin { tiles: vec![], set_in: vec![] })).unwrap().reply {
            Reply::Loaded { hash } => assert_eq!(hash, ""),
            other => panic!("pins cleared: {other:?}"),
        }
        assert_eq!(heights(r.call(&env(21, 0, Request::Tile { seed: 42, tile: c, noise: None })).unwrap()), free_tile);
        let noise = NoiseParams::default();
        let want = ProceduralSource::new(noise).generate(7, c, &Neighbourhood::default()).heights;
        assert_eq!(heights(r.call(&env(12, 0, Request::Tile { seed: 7, tile: c, noise: Some(noise) })).unwrap()), want);

        let (_, sketch) = crate::sketch::examples::all().swap_remove(0);
        let want = sketch_models.generator.generate(&sketch, crate::world::sketched::SKETCH_EXTENT_M, &mut Default::default(), 1);
        assert_eq!(heights(r.call(&env(13, 0, Request::Sketch { sketch: (&sketch).into(), extent_m: crate::world::sketched::SKETCH_EXTENT_M })).unwrap()), want);
        let want = sketch_models.generator.generate(&sketch, 512.0, &mut Default::default(), 1);
        assert_eq!(heights(r.call(&env(13, 0, Request::Sketch { sketch: (&sketch).into(), extent_m: 512.0 })).unwrap()), want, "the generator is told the request's extent");
        match r.call(&env(14, 0, Request::Variants { sketch: (&sketch).into(), n: 2, seed: 5 })).unwrap().reply {
            Reply::Sketches { sketches, heights, .. } => {
                let sketches: Vec<Sketch> = sketches.iter().map(|s| s.sketch().unwrap()).collect();
                assert_eq!(sketches, sketch_models.vae.variants(&sketch, 2, 5, &mut Default::default(), 1));
                assert_eq!(heights.len(), 2 * SKETCH_TERRAIN);
                assert_eq!(&heights[SKETCH_TERRAIN..], &sketch_models.generator.generate(&sketches[1], crate::world::sketched::SKETCH_EXTENT_M, &mut Default::default(), 1)[..]);
            }
            other => panic!("variants: {other:?}"),
        }
        let other = Sketch::filled(2);
        match r.call(&env(15, 0, Request::Blend { a: (&sketch).into(), b: (&other).into(), alpha: 0.25 })).unwrap().reply {
            Reply::Sketches { sketches, heights, .. } => {
                assert_eq!(sketches, vec![SketchBytes::from(&sketch_models.vae.interpolate(&sketch, &other, 0.25, &mut Default::default(), 1))]);
                assert_eq!(heights.len(), SKETCH_TERRAIN);
            }
            other => panic!("blend: {other:?}"),
        }
    }

    /// Once a request of world epoch 3 has arrived, a queued learned tile of epoch 2 is
    /// answered Stale at its next piece (unmade), and a later request of epoch 2 at once;
    /// requests of epoch 3 are made.
    #[test]
    fn world_requests_older_than_the_newest_epoch_are_answered_stale() {
        let mut r = Runner::new(1);
        let noise = NoiseParams::default();
        let Accepted::Paced(mut old) = r.accept(env(1, 2, Request::Tile { seed: 1, tile: TileCoord::new(0, 0), noise: None })) else { panic!("a learned tile is a task") };
        let Accepted::Now(a) = r.accept(env(2, 3, Request::Tile { seed: 1, tile: TileCoord::new(0, 0), noise: Some(noise) })) else { panic!("a procedural tile is answered now") };
        assert_eq!(heights(a).len(), crate::grid::TILE_SAMPLES.pow(2));
        assert_eq!(r.epoch(), 3);
        assert_eq!(r.step(&mut old).0, Some(Answer { id: 1, reply: Reply::Stale }));
        assert_eq!(r.handle(env(3, 2, Request::Enhance { level: 0, n: 1, side: 4, input: vec![0.0; 16] })), Answer { id: 3, reply: Reply::Stale });
        // Loads and sketches belong to no world: their epoch is not checked.
        assert!(!matches!(r.handle(env(4, 0, Request::Sketch { sketch: (&Sketch::filled(1)).into(), extent_m: crate::world::sketched::SKETCH_EXTENT_M })).reply, Reply::Stale));
    }

    /// Bytes that name no request kind (variant 99) get an error reply to their id that says
    /// the request is malformed.
    #[test]
    fn an_unknown_request_kind_gets_an_error_reply_to_its_id() {
        let mut bytes = env(77, 0, Request::Sketch { sketch: (&Sketch::filled(0)).into(), extent_m: crate::world::sketched::SKETCH_EXTENT_M }).encode();
        // id (1 byte varint), epoch (1 byte), rest (8 bytes), then the variant index.
        assert_eq!(bytes[10], 5, "Sketch is variant 5");
        bytes[10] = 99;
        let Accepted::Now(a) = Runner::new(1).accept_bytes(&bytes) else { panic!() };
        assert_eq!(a.id, 77);
        assert!(failed(&a).starts_with("malformed request"), "{a:?}");
    }

    /// Malformed payloads are error replies that say what is wrong, never a panic: truncated
    /// bytes, an empty message, a sketch pixel out of range, TEM windows of the wrong size or
    /// level, 0 variants, a blend α of 2, broken weight bytes, and requests before their
    /// models are loaded (the learned world's network work among them); 2000 random byte
    /// strings too.
    #[test]
    fn malformed_payloads_get_clear_error_replies_never_a_panic() {
        let mut r = Runner::new(1);
        let full = env(9, 0, Request::Sketch { sketch: (&Sketch::filled(0)).into(), extent_m: crate::world::sketched::SKETCH_EXTENT_M }).encode();
        let Accepted::Now(a) = r.accept_bytes(&full[..full.len() / 2]) else { panic!() };
        assert_eq!(a.id, 9);
        assert!(failed(&a).contains("malformed request"));
        let Accepted::Now(a) = r.accept_bytes(&[]) else { panic!() };
        assert_eq!(a.id, 0);
        let mut bad_pixel = full.clone();
        *bad_pixel.last_mut().unwrap() = 200;
        let a = r.handle(Envelope::decode(&bad_pixel).unwrap());
        assert!(failed(&a).contains("packed pixel 65535 is 200"), "{a:?}");
        let cases = [
            (Request::Enhance { level: 0, n: 2, side: 4, input: vec![0.0; 16] }, "needs 32 heights, not 16"),
            (Request::Enhance { level: 9, n: 1, side: 4, input: vec![0.0; 16] }, "no TEM level 9"),
            (Request::Variants { sketch: (&Sketch::filled(0)).into(), n: 0, seed: 1 }, "1 to 16 variants, not 0"),
            (Request::Blend { a: (&Sketch::filled(0)).into(), b: (&Sketch::filled(1)).into(), alpha: 2.0 }, "not 2"),
            (Request::LoadWorld { tcm: vec![1, 2, 3], grow: vec![] }, ""),
            (Request::LoadTem { files: vec![vec![0; 10]; 5] }, ""),
            (Request::Sketch { sketch: (&Sketch::filled(0)).into(), extent_m: crate::world::sketched::SKETCH_EXTENT_M }, "no sketch models loaded"),
            (Request::Tile { seed: 1, tile: TileCoord::new(0, 0), noise: None }, "no learned world loaded"),
            (Request::Enhance { level: 0, n: 1, side: 4, input: vec![0.0; 16] }, "no TEM loaded"),
            (Request::WorldWork { seed: 1, tile: TileCoord::new(0, 0), coarse: false }, "no learned world loaded"),
            (Request::RunWork { work: crate::world::learned::NetworkWork::None, halves: false }, "no learned world loaded"),
            (Request::AcceptWork { seed: 1, keys: crate::world::learned::NetworkWork::None.keys(), outputs: Vec::new(), ms: 0.0 }, "no learned world loaded"),
        ];
        for (k, (req, says)) in cases.into_iter().enumerate() {
            let a = r.handle(env(100 + k as u32, 0, req));
            assert_eq!(a.id, 100 + k as u32);
            assert!(failed(&a).contains(says) && !failed(&a).is_empty(), "case {k}: {a:?}");
        }
        let mut state = 1u64;
        for len in 0..2000usize {
            let bytes: Vec<u8> = (0..len % 64)
                .map(|_| {
                    state = crate::grid::mix64(state);
                    state as u8
                })
                .collect();
            if let Accepted::Paced(mut t) = r.accept_bytes(&bytes) {
                let _ = r.step(&mut t);
            }
        }
    }

    /// A sketch survives the wire: packed and read back it is the same sketch.
    #[test]
    fn a_sketch_packed_and_read_back_is_the_same_sketch() {
        for (_, s) in crate::sketch::examples::all() {
            assert_eq!(Sketch::from_packed(&s.packed()).unwrap(), s);
        }
    }

    /// A worker's queue answers loads and malformed bytes at once, takes tiles and TEM batches
    /// as tasks (the first one asks for the loop to start, the next joins it), makes them
    /// oldest first and ends the loop when none is left; the next task starts a new loop.
    #[test]
    fn the_queue_makes_tasks_oldest_first_and_ends_its_loop_when_none_is_left() {
        let mut q = Queue::new(1);
        let (a, start) = q.accept_bytes(&[1, 2, 3]);
        assert!(matches!(a, Some(Answer { reply: Reply::Failed(_), .. })) && !start);
        let tile = |id| env(id, 1, Request::Tile { seed: 1, tile: TileCoord::new(0, 0), noise: None }).encode();
        assert!(matches!(q.accept_bytes(&tile(5)), (None, true)));
        assert!(matches!(q.accept_bytes(&tile(6)), (None, false)));
        let mut ids = Vec::new();
        while let Some((answer, rest)) = q.next_piece() {
            assert_eq!(rest, 0.0, "no rest asked for");
            ids.extend(answer.map(|a| a.id));
        }
        assert_eq!(ids, vec![5, 6], "oldest first");
        assert!(matches!(q.accept_bytes(&tile(7)), (None, true)), "a new loop");
    }
}
