//! Speed of the world pipeline on the CPU: one procedural tile, one quadtree node gathered
//! from tiles, one node mesh (vertices + normals + skirts), TEM inference per quad, the
//! learned world's networks per tile, and the sketch models (a terrain per sketch, variants,
//! a blend).

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

use terrain::render::mesh::node_vertices;
use terrain::world::quadtree::{NodeData, NodeId};
use terrain::world::sketched::SKETCH_EXTENT_M;
use terrain::world::{Neighbourhood, ProceduralSource, TILE_SIZE_M, TileCoord, TileSource, WorldStream};

fn world(c: &mut Criterion) {
    let src = ProceduralSource::default();
    let mut k = 0;
    c.bench_function("procedural tile 128x128 (8 octaves)", |b| {
        b.iter(|| {
            k += 1;
            black_box(src.generate(3, TileCoord::new(k % 50, k / 50), &Neighbourhood::default()))
        })
    });
    let mut w = WorldStream::new(3, Box::new(ProceduralSource::default()), 1.0);
    w.update(TILE_SIZE_M * 0.5, TILE_SIZE_M * 0.5, 1e9);
    let id = NodeId { tile: TileCoord::new(0, 0), depth: 2, x: 1, y: 2 };
    c.bench_function("node gather (depth 2)", |b| b.iter(|| black_box(NodeData::from_world(id, &w))));
    let node = NodeData::from_world(id, &w).unwrap();
    c.bench_function("node mesh 33x33 + skirts", |b| b.iter(|| black_box(node_vertices(&node))));
    // One block of the learned world's 128 m field (EROSION_BLOCK_TILES² tiles) eroded as each of
    // its two stages does it: bumps on a slope.
    let n = terrain::world::learned::EROSION_BLOCK_TILES as usize * terrain::models::tcm::TILE_PX;
    let field: Vec<f32> = (0..n * n)
        .map(|p| {
            let (x, y) = ((p % n) as f32, (p / n) as f32);
            500.0 + 200.0 * (x * 0.3).sin() * (y * 0.27).cos() + 3.0 * x
        })
        .collect();
    c.bench_function("erosion of one 128 m block (learned::EROSION_BLOCK_TILES squared, learned::EROSION)", |b| {
        b.iter(|| {
            let mut h = field.clone();
            terrain::world::erosion::erode(&mut h, n, None, &terrain::world::learned::EROSION);
            black_box(h)
        })
    });
}

/// TEM inference per refined quad on the CPU (the project's kernels, shipped weights): one
/// level-0 window of 100² heights → 200² (the stored patch keeps 164²), alone and in a batch
/// of 4, on 1 thread and on every core. tools/tem_vs_onnx.py compares the same configurations
/// with ONNX Runtime.
fn tem(c: &mut Criterion) {
    use terrain::models::cpu::default_threads;
    use terrain::models::tem::{Exec, TemSet};
    use terrain::world::refine::INPUT_SIDE;
    let dir = terrain::repo_root().join("weights");
    let input: Vec<f32> = (0..INPUT_SIDE * INPUT_SIDE).map(|k| ((k % INPUT_SIDE) as f32 * 0.2).sin() * 40.0 + (k / INPUT_SIDE) as f32).collect();
    let four: Vec<f32> = (0..4).flat_map(|_| input.clone()).collect();
    let mut g = c.benchmark_group("tem cpu");
    g.sample_size(10);
    let mut threads = vec![1, default_threads()];
    threads.dedup();
    for t in threads {
        let tem = TemSet::load_dir(&dir, &Exec::Cpu { threads: t }).expect("weights/");
        g.bench_function(format!("1 quad, {t} thread(s) (level 0, 100² → 200²)"), |b| b.iter(|| black_box(tem.enhance_blocking(0, input.clone(), 1, INPUT_SIDE).unwrap())));
        g.bench_function(format!("batch of 4 quads, {t} thread(s)"), |b| b.iter(|| black_box(tem.enhance_blocking(0, four.clone(), 4, INPUT_SIDE).unwrap())));
    }
    g.finish();
}

/// The learned world on the CPU kernels, per tile, with networks of the shipped architecture
/// (random weights: the speed does not depend on their values): one 128 m tile from each phase's
/// neighbours (TCM), the ×4 step of one tile to 32 m, and a whole new 32 m tile in a fresh world
/// (its 128 m tile and the neighbours' that the schedule needs), on 1 thread and on every core.
fn learned(c: &mut Criterion) {
    use std::sync::Arc;
    use terrain::models::cpu::default_threads;
    use terrain::models::grow::{self, GrowCpu, GrowScratch};
    use terrain::models::tcm::{TILE_PX, TcmCpu, TcmScratch, assemble_input, phase_mask};
    use terrain::world::learned::{LearnedModels, LearnedSource};
    let tcm = TcmCpu::randomized(1, 0.05);
    let up = GrowCpu::randomized(2, 0.05);
    let tile = vec![500.0f32; TILE_PX * TILE_PX];
    let mut g = c.benchmark_group("learned world cpu");
    g.sample_size(10);
    for threads in [1, default_threads()] {
        for phase in 0..4 {
            let mask = phase_mask(phase);
            let tiles: [Option<&[f32]>; 9] = std::array::from_fn(|t| mask[t].then_some(tile.as_slice()));
            let x = assemble_input(&tiles, &[500.0; 9], &[0.5; 9], 7);
            let mut s = TcmScratch::default();
            g.bench_function(format!("TCM 128 m tile, phase {phase}, {threads} thread(s)"), |b| b.iter(|| black_box(tcm.forward(&x, &mut s, threads))));
        }
        // A phase's batch as the job queue hands it: the 4 tiles of that phase in a 4×4 area
        // (phase 3, three neighbours given), one after another with every thread on each tile.
        let mask = phase_mask(3);
        let tiles: [Option<&[f32]>; 9] = std::array::from_fn(|t| mask[t].then_some(tile.as_slice()));
        let batch: Vec<Vec<f32>> = (0..4).map(|k| assemble_input(&tiles, &[500.0; 9], &[0.5; 9], 7 + k)).collect();
        let mut s = TcmScratch::default();
        g.bench_function(format!("TCM phase batch of 4 tiles, one after another, {threads} thread(s) each"), |b| {
            b.iter(|| batch.iter().map(|x| black_box(tcm.forward(x, &mut s, threads))).count())
        });
        if threads > 1 {
            // The same batch split between the threads, one tile per thread at a time.
            g.bench_function(format!("TCM phase batch of 4 tiles, {threads} at a time, 1 thread each"), |b| {
                b.iter(|| {
                    std::thread::scope(|sc| {
                        for part in batch.chunks(batch.len().div_ceil(threads)) {
                            let tcm = &tcm;
                            sc.spawn(move || {
                                let mut s = TcmScratch::default();
                                part.iter().map(|x| black_box(tcm.forward(x, &mut s, 1))).count()
                            });
                        }
                    })
                })
            });
        }
        let window = vec![500.0f32; grow::WINDOW * grow::WINDOW];
        let (x, n64, n32) = grow::assemble(&window, 7, 0, 0);
        let mut s = GrowScratch::default();
        g.bench_function(format!("x4 step 128 -> 32 m, {threads} thread(s)"), |b| b.iter(|| black_box(up.forward(&x, &n64, &n32, grow::WINDOW, &mut s, threads))));
        let models = Arc::new(LearnedModels::from_parts(tcm.clone(), None, up.clone(), None, "bench"));
        let mut seed = 0;
        // A tile is drained over its second-stage block of 2×2 tiles, each drained before over
        // its first-stage block: the first tile of a fresh world makes the 4×4 ×4 steps under
        // them, the eroded 128 m tiles around those (two erosion stages over the network tiles
        // under them) and both drainage stages (its neighbours then mostly come from the
        // caches).
        g.bench_function(format!("first 32 m tile in a fresh world (4x4 x4 steps, two erosion and two drainage stages), {threads} thread(s)"), |b| {
            b.iter(|| {
                seed += 1;
                let src = LearnedSource::new(models.clone(), threads);
                black_box(src.generate(seed, TileCoord::new(1, 1), &Neighbourhood::default()))
            })
        });
    }
    g.finish();
}

/// The sketch models with the shipped weights: one sketch → 256² terrain (the generator, one
/// view as the page draws it, and the 8 views `terrain sketch` averages), four variants (the
/// VAE's encoder once, its decoder five times — the sketch's own code and four near it — and
/// the generator four times, one view each: what the page's Variants button and `terrain
/// sketch-variants --views 1` do) and one blend of two sketches (encoder twice, decoder three
/// times, generator once), on 1 thread and on every core.
fn sketch(c: &mut Criterion) {
    use terrain::models::cpu::default_threads;
    use terrain::models::sketch::{self as generator, SketchScratch};
    use terrain::models::sketch_vae::{self as vae, SketchModels};
    let dir = terrain::repo_root().join("weights");
    let read = |f: &str| std::fs::read(dir.join(f)).expect("weights/");
    let m = SketchModels::from_bytes(&read(generator::WEIGHT_FILE), &read(vae::WEIGHT_FILE)).expect("sketch weights");
    let examples = terrain::sketch::examples::all();
    let (a, b) = (&examples[0].1, &examples[1].1);
    let mut g = c.benchmark_group("sketch cpu");
    g.sample_size(10);
    let mut threads = vec![1, default_threads()];
    threads.dedup();
    for t in threads {
        let mut s = SketchScratch::default();
        g.bench_function(format!("generator, one sketch -> 256² terrain, {t} thread(s)"), |bn| bn.iter(|| black_box(m.generator.generate(a, SKETCH_EXTENT_M, &mut s, t))));
        let views = generator::CLI_VIEWS;
        g.bench_function(format!("generator, {views} views averaged (terrain sketch's default), {t} thread(s)"), |bn| {
            bn.iter(|| black_box(m.generator.generate_views(a, SKETCH_EXTENT_M, views, &mut s, t)))
        });
        g.bench_function(format!("4 variants with their terrains, {t} thread(s)"), |bn| {
            bn.iter(|| {
                let v = m.vae.variants(a, 4, 7, &mut Default::default(), t);
                black_box(v.iter().map(|k| m.generator.generate(k, SKETCH_EXTENT_M, &mut s, t)).collect::<Vec<_>>())
            })
        });
        g.bench_function(format!("blend of two sketches with its terrain, {t} thread(s)"), |bn| {
            bn.iter(|| {
                let k = m.vae.interpolate(a, b, 0.5, &mut Default::default(), t);
                black_box(m.generator.generate(&k, SKETCH_EXTENT_M, &mut s, t))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, world, tem, learned, sketch);
criterion_main!(benches);
