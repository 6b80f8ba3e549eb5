//! Speed of the world pipeline on the CPU: one procedural tile, one quadtree node gathered
//! from tiles, and one node mesh (vertices + normals + skirts).

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

criterion_group!(benches, world);
criterion_main!(benches);
