//! Node meshes: a `NODE_GRID`² vertex grid with finite-difference normals and skirts that hang
//! below every edge, and the one index buffer all nodes share.

use bytemuck::{Pod, Zeroable};

use crate::world::quadtree::{NODE_GRID, NODE_QUADS, NodeData};

/// One terrain vertex: position relative to the node's north-west corner in x and z, absolute
/// height in y (metres), and the unit surface normal.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    /// (x, height, z) in metres; x and z relative to the node origin.
    pub position: [f32; 3],
    /// Unit normal.
    pub normal: [f32; 3],
}

/// Vertices in one node mesh: the grid, then one skirt vertex per edge vertex (4 edges).
pub const NODE_VERTICES: usize = NODE_GRID * NODE_GRID + 4 * NODE_GRID;

/// The vertices of node `d`: grid vertices row by row, then the skirts of the north, south,
/// west and east edges (each `NODE_GRID` vertices, `d.skirt_m` below the edge vertex, with its
/// normal so lighting continues down the skirt).
pub fn node_vertices(d: &NodeData) -> Vec<Vertex> {
    let s = d.id.spacing_m() as f32;
    let mut out = Vec::with_capacity(NODE_VERTICES);
    for r in 0..NODE_GRID as i32 {
        for c in 0..NODE_GRID as i32 {
            let dx = (d.at(c + 1, r) - d.at(c - 1, r)) / (2.0 * s);
            let dz = (d.at(c, r + 1) - d.at(c, r - 1)) / (2.0 * s);
            let n = glam::Vec3::new(-dx, 1.0, -dz).normalize();
            out.push(Vertex { position: [c as f32 * s, d.at(c, r), r as f32 * s], normal: n.to_array() });
        }
    }
    for edge in 0..4 {
        for k in 0..NODE_GRID {
            let top = out[edge_vertex(edge, k)];
            out.push(Vertex { position: [top.position[0], top.position[1] - d.skirt_m, top.position[2]], normal: top.normal });
        }
    }
    out
}

/// Index of grid vertex k (0..NODE_GRID) along edge `edge` (0 north, 1 south, 2 west, 3 east).
fn edge_vertex(edge: usize, k: usize) -> usize {
    let last = NODE_QUADS;
    match edge {
        0 => k,
        1 => last * NODE_GRID + k,
        2 => k * NODE_GRID,
        _ => k * NODE_GRID + last,
    }
}

/// The triangle list shared by every node: two triangles per grid quad, then two per skirt
/// segment joining each edge segment to the skirt vertices below it.
pub fn node_indices() -> Vec<u16> {
    node_indices_strided(1)
}

/// [`node_indices`] over every `stride`-th vertex (a divisor of `NODE_QUADS`): the grid's
/// quads `stride` vertices wide and the skirt segments between the same edge vertices.
pub fn node_indices_strided(stride: usize) -> Vec<u16> {
    assert!(stride >= 1 && NODE_QUADS.is_multiple_of(stride), "stride {stride}");
    let (g, s, q) = (NODE_GRID, stride, NODE_QUADS / stride);
    let mut idx = Vec::with_capacity(q * q * 6 + 4 * q * 6);
    for r in (0..NODE_QUADS).step_by(s) {
        for c in (0..NODE_QUADS).step_by(s) {
            let (a, b, cc, d) = (r * g + c, r * g + c + s, (r + s) * g + c, (r + s) * g + c + s);
            // Alternate the diagonal so the triangulation has no directional bias.
            if (r / s + c / s) % 2 == 0 {
                idx.extend([a, cc, b, b, cc, d].map(|v| v as u16));
            } else {
                idx.extend([a, cc, d, a, d, b].map(|v| v as u16));
            }
        }
    }
    let skirt0 = g * g;
    for edge in 0..4 {
        for k in (0..NODE_QUADS).step_by(s) {
            let (t0, t1) = (edge_vertex(edge, k), edge_vertex(edge, k + s));
            let (s0, s1) = (skirt0 + edge * g + k, skirt0 + edge * g + k + s);
            idx.extend([t0, s0, t1, t1, s0, s1].map(|v| v as u16));
        }
    }
    idx
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::TileCoord;
    use crate::world::quadtree::{NODE_APRON_GRID, NodeId};
    use std::collections::HashMap;

    fn edge_counts(idx: &[u16]) -> HashMap<(u16, u16), usize> {
        let mut m = HashMap::new();
        for t in idx.chunks(3) {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *m.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        m
    }

    #[test]
    fn index_buffer_is_crack_free() {
        let idx = node_indices();
        assert_eq!(idx.len() % 3, 0);
        assert!(idx.iter().all(|&i| (i as usize) < NODE_VERTICES));
        let counts = edge_counts(&idx[..NODE_QUADS * NODE_QUADS * 6]);
        let skirt_counts = edge_counts(&idx[NODE_QUADS * NODE_QUADS * 6..]);
        let on_border = |v: u16| {
            let (r, c) = (v as usize / NODE_GRID, v as usize % NODE_GRID);
            r == 0 || c == 0 || r == NODE_QUADS || c == NODE_QUADS
        };
        let mut border_edges = 0;
        for (&(a, b), &n) in &counts {
            let (ra, ca, rb, cb) = (a as usize / NODE_GRID, a as usize % NODE_GRID, b as usize / NODE_GRID, b as usize % NODE_GRID);
            let boundary = on_border(a) && on_border(b) && (ra == rb && (ra == 0 || ra == NODE_QUADS) || ca == cb && (ca == 0 || ca == NODE_QUADS));
            if boundary {
                // Each surface edge on the node border has exactly one surface triangle and a
                // skirt triangle hanging from it: no gap can open along it.
                assert_eq!(n, 1, "border edge {a}-{b}");
                assert_eq!(skirt_counts.get(&(a, b)), Some(&1), "border edge {a}-{b} has no skirt");
                border_edges += 1;
            } else {
                assert_eq!(n, 2, "interior edge {a}-{b} shared by {n} triangles");
            }
        }
        assert_eq!(border_edges, 4 * NODE_QUADS);
    }

    /// For every draw stride (1: every vertex; 4: the far field's every 4th), the surface
    /// triangles of the index buffer are 2 per drawn quad, all wound the same way, and their
    /// areas (projected on the ground) add up to the node's square exactly; the skirts of a
    /// strided buffer join the same edge vertices as its surface (each edge segment is shared
    /// by one surface and one skirt triangle).
    #[test]
    fn surface_triangles_tile_the_node_square() {
        for stride in crate::world::quadtree::DRAW_STRIDES.map(usize::from) {
            surface_tiles_the_square(stride);
        }
    }

    fn surface_tiles_the_square(stride: usize) {
        let idx = node_indices_strided(stride);
        let grid = (NODE_GRID * NODE_GRID) as u16;
        let quads = NODE_QUADS / stride;
        let surface: Vec<&[u16]> = idx.chunks_exact(3).filter(|t| t.iter().all(|&i| i < grid)).collect();
        assert_eq!(surface.len(), 2 * quads * quads);
        let skirts = &idx[surface.len() * 3..];
        let (sc, kc) = (edge_counts(&idx[..surface.len() * 3]), edge_counts(skirts));
        let open: Vec<_> = sc.iter().filter(|(_, n)| **n == 1).map(|(e, _)| *e).collect();
        assert_eq!(open.len(), 4 * quads, "stride {stride}: the border has 4 × {quads} segments");
        assert!(open.iter().all(|e| kc.get(e) == Some(&1)), "stride {stride}: a border segment without its skirt");
        let xz = |i: u16| ((i as usize % NODE_GRID) as f64, (i as usize / NODE_GRID) as f64);
        let cross = |t: &[u16]| {
            let (a, b, c) = (xz(t[0]), xz(t[1]), xz(t[2]));
            (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)
        };
        let sign = cross(surface[0]).signum();
        let mut area = 0.0;
        for t in &surface {
            let c = cross(t);
            assert!(c * sign > 0.0, "triangle {t:?} is wound the other way or degenerate");
            area += c.abs() / 2.0;
        }
        assert_eq!(area, (NODE_QUADS * NODE_QUADS) as f64, "stride {stride}");
    }

    #[test]
    fn vertices_carry_heights_normals_and_skirts() {
        // A plane rising 1 m per metre east: normals all tilt to (−1, 1, 0)/√2.
        let id = NodeId { tile: TileCoord::new(0, 0), depth: 2, x: 0, y: 0 };
        let s = id.spacing_m() as f32;
        let mut h = Vec::new();
        for _r in 0..NODE_APRON_GRID {
            for c in 0..NODE_APRON_GRID {
                h.push((c as f32 - 1.0) * s);
            }
        }
        let d = NodeData::new(id, h, 7.0);
        let v = node_vertices(&d);
        assert_eq!(v.len(), NODE_VERTICES);
        assert_eq!(v[5].position, [5.0 * s, 5.0 * s, 0.0]);
        let n = v[NODE_GRID + 3].normal;
        assert!((n[0] + std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-5 && n[2].abs() < 1e-6);
        let east_skirt_top = v[NODE_GRID * NODE_GRID + 3 * NODE_GRID + 4];
        assert_eq!(east_skirt_top.position[1], 32.0 * s - 7.0);
        assert_eq!(east_skirt_top.position[0], 32.0 * s);
    }
}
