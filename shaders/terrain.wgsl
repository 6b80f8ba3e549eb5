// Terrain: node meshes (grid + skirts), coloured by elevation and slope, lit by the sun and
// the sky, fogged with distance.

struct VertexIn {
    @location(0) position: vec3<f32>,   // x, z relative to the node origin; y absolute height (m)
    @location(1) normal: vec3<f32>,
    @location(2) offset: vec3<f32>,     // node origin − eye (m); y = −eye height
    @location(3) depth: f32,            // quadtree depth of the node
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) rel: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) height: f32,
    @location(3) depth: f32,
};

@vertex
fn vs_main(v: VertexIn) -> VertexOut {
    var o: VertexOut;
    o.rel = v.position + v.offset;
    o.clip = g.view_proj * vec4<f32>(o.rel, 1.0);
    o.normal = v.normal;
    o.height = v.position.y;
    o.depth = v.depth;
    return o;
}

// `n`: the smooth (vertex) normal; `face_slope`: 1 − |y| of the triangle's own normal. Snow
// lies by the triangle's slope, so a ridge's crest (level at its vertices, steep on both
// faces) stays rock instead of a dotted white line along every ridge.
fn terrain_albedo(h: f32, n: vec3<f32>, face_slope: f32) -> vec3<f32> {
    let slope = max(1.0 - n.y, face_slope); // 0 flat … 1 vertical
    let amp = max(g.fog.w, 1.0);
    let rel_h = (h - g.fog.z) / amp;      // 0 at the water line, ~1 at the top
    let sand = vec3<f32>(0.76, 0.70, 0.50);
    let grass = vec3<f32>(0.26, 0.42, 0.16);
    let forest = vec3<f32>(0.16, 0.28, 0.12);
    let rock = vec3<f32>(0.42, 0.39, 0.36);
    let snow = vec3<f32>(0.95, 0.96, 0.98);
    var c = mix(grass, forest, smoothstep(0.05, 0.25, rel_h));
    c = mix(sand, c, smoothstep(0.0, 0.012, rel_h));
    c = mix(c, rock, smoothstep(0.40, 0.60, rel_h));
    c = mix(c, rock, smoothstep(0.25, 0.45, slope));
    let snow_line = 0.62 + face_slope * 0.5;
    // A wide ramp, so neighbouring triangles of different slope do not show as snow facets.
    c = mix(c, snow, smoothstep(snow_line, snow_line + 0.06, rel_h) * (1.0 - smoothstep(0.15, 0.5, face_slope)));
    return c;
}

@fragment
fn fs_main(i: VertexOut) -> @location(0) vec4<f32> {
    let n = normalize(i.normal);
    let face = normalize(cross(dpdx(i.rel), dpdy(i.rel)));
    let face_slope = 1.0 - abs(face.y);
    var albedo = terrain_albedo(i.height, n, face_slope);
    if (g.params.x > 0.5) {
        let tint = array<vec3<f32>, 4>(vec3<f32>(1.0, 0.3, 0.3), vec3<f32>(0.3, 1.0, 0.3), vec3<f32>(0.3, 0.5, 1.0), vec3<f32>(1.0, 1.0, 0.3));
        albedo = mix(albedo, tint[u32(i.depth) % 4u], 0.45);
    }
    let sun = max(dot(n, g.sun.xyz), 0.0);
    let sky_light = mix(vec3<f32>(0.20, 0.18, 0.15), vec3<f32>(0.45, 0.55, 0.70), n.y * 0.5 + 0.5);
    let lit = albedo * (vec3<f32>(1.0, 0.95, 0.85) * sun * 1.1 + sky_light * 0.55);
    // Level ground is water: a lake the drainage left (level to 1 mm a sample) or the sketch's
    // plain. Slopes under ~0.1° are water, over ~0.25° ground (1 − n.y ≈ slope² / 2), by the
    // interpolated normal (a smooth shore) and by the triangle's own (a lone level vertex on
    // a slope is no pond).
    let lake = (1.0 - smoothstep(2e-6, 1e-5, 1.0 - n.y)) * (1.0 - smoothstep(2e-6, 1e-5, face_slope));
    let c = mix(lit, water_colour(i.rel).rgb, lake);
    return vec4<f32>(apply_fog(c, i.rel), 1.0);
}
