// Sky: one full-screen triangle; each pixel's view ray picks its colour.

struct SkyOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) ndc: vec2<f32>,
};

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> SkyOut {
    let p = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u)) * 2.0 - 1.0;
    var o: SkyOut;
    o.clip = vec4<f32>(p, 0.0, 1.0);
    o.ndc = p;
    return o;
}

@fragment
fn fs_main(i: SkyOut) -> @location(0) vec4<f32> {
    let p = g.inv_view_proj * vec4<f32>(i.ndc, 0.5, 1.0);
    let dir = normalize(p.xyz / p.w);
    return to_target(vec4<f32>(sky_colour(dir), 1.0));
}
