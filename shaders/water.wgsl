// Water: one large square at the water level around the eye, reflecting the sky with a
// Fresnel term, showing the sun's glint, fogged like the terrain.

struct WaterOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) rel: vec3<f32>,
};

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> WaterOut {
    let corners = array<vec2<f32>, 6>(vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, -1.0), vec2<f32>(1.0, 1.0), vec2<f32>(-1.0, 1.0));
    let c = corners[i] * g.fog.y * 1.5;
    var o: WaterOut;
    o.rel = vec3<f32>(c.x, g.fog.z - g.eye.y, c.y);
    o.clip = g.view_proj * vec4<f32>(o.rel, 1.0);
    return o;
}

@fragment
fn fs_main(i: WaterOut) -> @location(0) vec4<f32> {
    let view = normalize(i.rel);
    // Small analytic ripples perturb the normal so the surface is not a mirror.
    let p = (i.rel.xz + g.eye.xz) * 0.02;
    let t = g.params.y;
    let ripple = vec2<f32>(sin(p.x * 1.7 + t * 1.3) + sin(p.y * 2.3 - t), cos(p.y * 1.9 + t * 1.1) + cos(p.x * 2.9 - t * 0.7)) * 0.02;
    let n = normalize(vec3<f32>(ripple.x, 1.0, ripple.y));
    let r = reflect(view, n);
    let fresnel = 0.04 + 0.96 * pow(1.0 - max(dot(-view, n), 0.0), 5.0);
    let deep = vec3<f32>(0.03, 0.12, 0.20);
    var c = mix(deep, sky_colour(r), fresnel);
    c += vec3<f32>(1.0, 0.9, 0.7) * pow(max(dot(r, g.sun.xyz), 0.0), 400.0) * 3.0;
    return vec4<f32>(apply_fog(c, i.rel), mix(0.80, 1.0, fresnel));
}
