// Terrain: node meshes (grid + skirts). Full shading: materials chosen per pixel from the
// surface itself (slope, altitude, aspect, world-space detail noise), normals with detail below
// the mesh spacing, the sun (with cast shadows from the shadow cascades) and the sky, aerial
// perspective. Plain shading (slow devices, `shade=plain`): colours by elevation and slope,
// lit by the sun and the sky, fogged with distance.

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

// Level ground is water: a lake the drainage left (level to 1 mm a sample) or the sketch's
// plain. Slopes under ~0.1° are water, over ~0.25° ground (1 − n.y ≈ slope² / 2), by the
// interpolated normal `n` (a smooth shore) and by the triangle's own, `face_slope` = 1 − |y| of
// it (a lone level vertex on a slope is no pond). 1 water, 0 ground.
fn lake_mask(n: vec3<f32>, face_slope: f32) -> f32 {
    return (1.0 - smoothstep(2e-6, 1e-5, 1.0 - n.y)) * (1.0 - smoothstep(2e-6, 1e-5, face_slope));
}

// The colour a node of quadtree `depth` is tinted with when nodes are coloured by depth.
fn depth_tint(depth: f32) -> vec3<f32> {
    let tint = array<vec3<f32>, 4>(vec3<f32>(1.0, 0.3, 0.3), vec3<f32>(0.3, 1.0, 0.3), vec3<f32>(0.3, 0.5, 1.0), vec3<f32>(1.0, 1.0, 0.3));
    return tint[u32(depth) % 4u];
}

// A hash of an integer lattice point, uniform in [0, 1).
fn hash2(c: vec2<i32>) -> f32 {
    var h = (bitcast<u32>(c.x) * 1597334673u) ^ (bitcast<u32>(c.y) * 3812015801u);
    h = (h ^ (h >> 15u)) * 2246822519u;
    return f32(h >> 8u) * (1.0 / 16777216.0);
}

// Value noise in [0, 1) and its gradient (per unit of `p`), quintic interpolation.
fn vnoise(p: vec2<f32>) -> vec3<f32> {
    let i = floor(p);
    let f = p - i;
    let c = vec2<i32>(i);
    let u = f * f * f * (f * (f * 6.0 - 15.0) + 10.0);
    let du = 30.0 * f * f * (f * (f - 2.0) + 1.0);
    let a = hash2(c);
    let b = hash2(c + vec2<i32>(1, 0));
    let e = hash2(c + vec2<i32>(0, 1));
    let d = hash2(c + vec2<i32>(1, 1));
    let k1 = b - a;
    let k2 = e - a;
    let k4 = a - b - e + d;
    return vec3<f32>(a + k1 * u.x + k2 * u.y + k4 * u.x * u.y, du * vec2<f32>(k1 + k4 * u.y, k2 + k4 * u.x));
}

// Detail of the ground below the mesh spacing: four octaves of noise from 60 m down to 3.8 m
// at world positions `w` (m), each rotated against the last so no grid shows, each fading out
// where a pixel covers more than a third of its wavelength (`footprint`: metres a pixel).
// Returns the detail's value (within ±0.5, the coarse octaves weighing most), the gradient
// of a surface whose every octave is as steep as the last (its height in proportion to the
// wavelength), and the coarsest octave's value (0..1).
fn detail(w: vec2<f32>, footprint: f32) -> vec4<f32> {
    var value = 0.0;
    var coarse = 0.5;
    var grad = vec2<f32>(0.0);
    var wavelength = 60.0;
    var weight = 0.5;
    let rot = mat2x2<f32>(0.80, 0.60, -0.60, 0.80);
    var r = rot;
    for (var k = 0; k < 4; k++) {
        let fade = 1.0 - smoothstep(wavelength * 0.15, wavelength * 0.35, footprint);
        if (fade <= 0.0) {
            break;
        }
        let n = vnoise((r * w) / wavelength + vec2<f32>(f32(k) * 17.3, f32(k) * 9.1));
        value += (n.x - 0.5) * fade * weight;
        if (k == 0) {
            coarse = mix(0.5, n.x, fade);
        }
        // d/dw of n(R w / λ) · λ = Rᵀ n′.
        grad += (transpose(r) * n.yz) * fade;
        r = rot * r;
        wavelength *= 0.4;
        weight *= 0.55;
    }
    return vec4<f32>(value, grad, coarse);
}

// The sun's visibility at camera-relative `rel` with normal `n`: 1 lit, 0 in the terrain's
// shadow, from the near cascade within its range and the far one beyond, 2×2 filtered; offset
// along the normal by a few texels against self-shadowing of the coarse casters.
fn sun_visibility(rel: vec3<f32>, n: vec3<f32>) -> f32 {
    let d = length(rel);
    if (d > g.shadow_info.y) {
        return 1.0;
    }
    var layer = 0;
    var texel = g.shadow_info.z;
    if (d > g.shadow_info.x) {
        layer = 1;
        texel = g.shadow_info.w;
    }
    let p = rel + n * texel * 2.5 + g.sun.xyz * texel * 2.0;
    let q = g.shadow[layer] * vec4<f32>(p, 1.0);
    let uv = vec2<f32>(q.x * 0.5 + 0.5, 0.5 - q.y * 0.5);
    if (any(uv < vec2<f32>(0.0)) || any(uv > vec2<f32>(1.0)) || q.z > 1.0) {
        return 1.0;
    }
    // One 2×2-filtered comparison (soft to a texel; four taps cost a third more frame on a
    // software rasteriser for edges the coarse casters make ragged anyway).
    let s = textureSampleCompareLevel(shadow_map, shadow_sampler, uv, layer, q.z);
    // Fade the far cascade out before its end, so the shadowed distance has no edge.
    let fade = smoothstep(g.shadow_info.y * 0.85, g.shadow_info.y, d);
    return mix(s, 1.0, fade);
}

// The ground's albedo at one pixel: `ns` the smooth (mesh) normal, `nd` with detail, `h`
// height (m), `w` world position (m), `dn` the detail noise's value, `coarse` its coarsest
// octave's (0..1, 60 m), `footprint` metres a pixel.
fn ground_albedo(ns: vec3<f32>, nd: vec3<f32>, h: f32, w: vec2<f32>, dn: f32, coarse: f32, footprint: f32) -> vec3<f32> {
    let amp = max(g.fog.w, 1.0);
    let rel_h = (h - g.fog.z) / amp;
    // Large patches (400 m and 60 m) that move every boundary, so none follows the mesh.
    let patch_a = vnoise(mat2x2<f32>(0.6, -0.8, 0.8, 0.6) * w / 410.0 + vec2<f32>(3.1, 7.7)).x;
    let patch_b = coarse;
    let wobble = (patch_a - 0.5) * 0.8 + (patch_b - 0.5) * 0.4 + dn * 0.3;
    let slope = 1.0 - ns.y;                  // 0 level … 1 vertical (smooth)
    let slope_d = 1.0 - nd.y;                // with detail
    // Facing the sun's side of the sky (aspect): south-west faces lose snow first.
    let sunny = dot(normalize(ns.xz + vec2<f32>(1e-4, 0.0)), normalize(g.sun.xz)) * smoothstep(0.02, 0.2, slope);

    let sand = vec3<f32>(0.55, 0.51, 0.41);
    let meadow_low = vec3<f32>(0.24, 0.31, 0.14);
    let forest = vec3<f32>(0.085, 0.13, 0.075);
    let meadow_alpine = vec3<f32>(0.33, 0.34, 0.21);
    let scree = vec3<f32>(0.47, 0.45, 0.41);
    let rock_a = vec3<f32>(0.30, 0.29, 0.27);
    let rock_b = vec3<f32>(0.40, 0.37, 0.33);
    let snow = vec3<f32>(0.92, 0.94, 0.97);

    // Vegetation by altitude: valley meadows, then forest, then alpine meadow above the
    // tree line (which dips where the ground is steep or faces away from the sun).
    let tree_line = 0.42 + wobble * 0.06 + sunny * 0.03 - slope * 0.15;
    let forest_w = smoothstep(0.02, 0.08, rel_h + wobble * 0.03) * (1.0 - smoothstep(tree_line - 0.04, tree_line + 0.03, rel_h));
    // Forest thins where the ground is level (meadows on valley floors and benches) and in
    // the large patches' low places, with soft, ragged edges.
    let open_ground = (1.0 - smoothstep(0.01, 0.12, slope)) * 0.5 + smoothstep(0.55, 0.2, patch_a) * 0.5;
    let density = clamp(1.0 - open_ground + (patch_b - 0.5) * 0.5 + dn * 0.2, 0.0, 1.0);
    var c = mix(meadow_low, meadow_alpine, smoothstep(tree_line - 0.05, tree_line + 0.08, rel_h));
    c = mix(c, forest * (0.85 + dn * 0.3), forest_w * smoothstep(0.1, 0.9, density));
    c = mix(sand, c, smoothstep(0.0, 0.01, rel_h));
    // Scree below the cliffs: moderately steep high ground.
    let scree_w = smoothstep(0.12, 0.22, slope_d + wobble * 0.08) * smoothstep(tree_line - 0.1, tree_line + 0.05, rel_h);
    c = mix(c, scree * (0.9 + dn * 0.3), scree_w);
    // Bare rock on steep faces, banded with height (strata) and speckled.
    // Strata 88 m apart in height, fading where a pixel spans several of them.
    let strata = 0.5 + 0.5 * sin(h / 14.0 + patch_b * 9.0) * (1.0 - smoothstep(3.0, 10.0, footprint));
    let rock = mix(rock_a, rock_b, strata) * (0.9 + dn * 0.25);
    let rock_w = smoothstep(0.22, 0.36, slope_d + wobble * 0.1) + smoothstep(0.62, 0.78, rel_h + wobble * 0.1) * smoothstep(0.05, 0.15, slope) * 0.7;
    c = mix(c, rock, clamp(rock_w, 0.0, 1.0));
    // Snow above a line that is lower on shaded faces; it does not hold on steep rock.
    let snow_line = 0.66 + wobble * 0.08 + sunny * 0.07;
    let snow_w = smoothstep(snow_line, snow_line + 0.05, rel_h) * (1.0 - smoothstep(0.30, 0.45, slope_d + dn * 0.1));
    c = mix(c, snow, snow_w);
    return c;
}

fn full_colour(i: VertexOut) -> vec3<f32> {
    let ns = normalize(i.normal);
    let w = i.rel.xz + g.eye.xz;
    let dx = dpdx(i.rel);
    let dy = dpdy(i.rel);
    let footprint = max(length(dx), length(dy));
    let d = detail(w, footprint);
    // Rougher where it is steep (rock) than on meadows.
    let rough = mix(0.07, 0.3, smoothstep(0.15, 0.4, 1.0 - ns.y));
    let nd = normalize(ns - vec3<f32>(d.y, 0.0, d.z) * rough);
    var albedo = ground_albedo(ns, nd, i.height, w, d.x, d.w, footprint);
    if (g.params.x > 0.5) {
        albedo = mix(albedo, depth_tint(i.depth), 0.45);
    }
    let sun_dir = g.sun.xyz;
    let lit_sun = max(dot(nd, sun_dir), 0.0) * sun_visibility(i.rel, ns);
    // Sky light from the upper hemisphere (bluish) and light bounced from the ground (warm),
    // less in hollows of the detail.
    let cavity = clamp(0.75 + d.x * 0.5, 0.45, 1.0);
    let sky_light = mix(vec3<f32>(0.16, 0.15, 0.12), vec3<f32>(0.40, 0.50, 0.66), nd.y * 0.5 + 0.5) * cavity;
    var c = albedo * (vec3<f32>(1.0, 0.93, 0.80) * lit_sun * 1.45 + sky_light * 0.75);
    let lake = lake_mask(ns, 1.0 - abs(normalize(cross(dx, dy)).y));
    if (lake > 0.0) {
        c = mix(c, water_colour(i.rel).rgb, lake);
    }
    return c;
}

fn plain_colour(i: VertexOut) -> vec3<f32> {
    let n = normalize(i.normal);
    let face = normalize(cross(dpdx(i.rel), dpdy(i.rel)));
    let face_slope = 1.0 - abs(face.y);
    var albedo = terrain_albedo(i.height, n, face_slope);
    if (g.params.x > 0.5) {
        albedo = mix(albedo, depth_tint(i.depth), 0.45);
    }
    let sun = max(dot(n, g.sun.xyz), 0.0);
    let sky_light = mix(vec3<f32>(0.20, 0.18, 0.15), vec3<f32>(0.45, 0.55, 0.70), n.y * 0.5 + 0.5);
    let lit = albedo * (vec3<f32>(1.0, 0.95, 0.85) * sun * 1.1 + sky_light * 0.55);
    return mix(lit, water_colour(i.rel).rgb, lake_mask(n, face_slope));
}

// Two entry points, one pipeline each: with both shadings behind one branch a software
// rasteriser paid for both (the plain frame took twice as long on llvmpipe).
@fragment
fn fs_full(i: VertexOut) -> @location(0) vec4<f32> {
    return to_target(vec4<f32>(aerial(full_colour(i), i.rel), 1.0));
}

@fragment
fn fs_plain(i: VertexOut) -> @location(0) vec4<f32> {
    return to_target(vec4<f32>(apply_fog(plain_colour(i), i.rel), 1.0));
}
