// Shared by every terrain pass: per-frame uniforms, the sky colour and distance fog.
// Positions are camera-relative metres (the eye at the origin), y up.

struct Globals {
    view_proj: mat4x4<f32>,      // camera-relative view-projection (reverse-Z)
    inv_view_proj: mat4x4<f32>,  // its inverse
    eye: vec4<f32>,              // eye position in world metres (x, y, z), w unused
    sun: vec4<f32>,              // unit vector towards the sun, w unused
    fog: vec4<f32>,              // x fog start (m), y fog end (m), z water level (m), w terrain amplitude (m)
    params: vec4<f32>,           // x: colour nodes by depth (0/1), y: time (s)
};

@group(0) @binding(0) var<uniform> g: Globals;

fn sky_colour(dir: vec3<f32>) -> vec3<f32> {
    let up = clamp(dir.y, 0.0, 1.0);
    let horizon = vec3<f32>(0.68, 0.78, 0.90);
    let zenith = vec3<f32>(0.16, 0.36, 0.72);
    var c = mix(horizon, zenith, pow(up, 0.55));
    // Below the horizon (seen only through fog) fade towards a hazy ground tone.
    c = mix(c, vec3<f32>(0.55, 0.60, 0.65), clamp(-dir.y * 4.0, 0.0, 1.0));
    let s = max(dot(dir, g.sun.xyz), 0.0);
    c += vec3<f32>(1.0, 0.92, 0.75) * (pow(s, 900.0) * 6.0 + pow(s, 12.0) * 0.22);
    return c;
}

fn apply_fog(c: vec3<f32>, rel: vec3<f32>) -> vec3<f32> {
    let d = length(rel);
    let t = clamp((d - g.fog.x) / max(g.fog.y - g.fog.x, 1.0), 0.0, 1.0);
    let f = t * t * (3.0 - 2.0 * t);
    let haze = sky_colour(normalize(vec3<f32>(rel.x, max(rel.y, 0.0) * 0.3, rel.z)));
    return mix(c, haze, f);
}
