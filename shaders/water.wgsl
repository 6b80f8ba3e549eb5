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
    let w = water_colour(i.rel);
    var c: vec3<f32>;
    if (full_shading()) {
        c = aerial(w.rgb, i.rel);
    } else {
        c = apply_fog(w.rgb, i.rel);
    }
    return to_target(vec4<f32>(c, mix(0.80, 1.0, w.a)));
}
