// Shadow cascades: the terrain's node meshes drawn as depth from the sun (one cascade a pass).

struct Cascade {
    view_proj: mat4x4<f32>, // camera-relative metres to the cascade's clip space
};

@group(0) @binding(0) var<uniform> cascade: Cascade;

struct VertexIn {
    @location(0) position: vec3<f32>,   // x, z relative to the node origin; y absolute height (m)
    @location(1) normal: vec3<f32>,
    @location(2) offset: vec3<f32>,     // node origin − eye (m); y = −eye height
    @location(3) depth: f32,
};

@vertex
fn vs_main(v: VertexIn) -> @builtin(position) vec4<f32> {
    return cascade.view_proj * vec4<f32>(v.position + v.offset, 1.0);
}
