//! Speed of the world pipeline on the CPU: one procedural tile, one quadtree node gathered
//! from tiles, one node mesh (vertices + normals + skirts), and TEM inference per quad.

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

use terrain::render::mesh::node_vertices;
use terrain::world::quadtree::{NodeData, NodeId};
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
}

/// TEM inference per refined quad on the CPU (the project's kernels, shipped weights): one
/// level-0 window of 100² heights → 200² (the stored patch keeps 164²), alone and in a batch
/// of 4, on 1 thread and on every core. tools/tem_vs_onnx.py compares the same configurations
/// with ONNX Runtime.
fn tem(c: &mut Criterion) {
    use terrain::models::cpu::default_threads;
    use terrain::models::tem::{Exec, TemSet};
    use terrain::world::refine::INPUT_SIDE;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("weights");
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

criterion_group!(benches, world, tem);
criterion_main!(benches);
