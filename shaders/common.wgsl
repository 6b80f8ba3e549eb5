// Shared by every terrain pass: per-frame uniforms, the sky colour and distance fog.
// Positions are camera-relative metres (the eye at the origin), y up.

struct Globals {
    view_proj: mat4x4<f32>,      // camera-relative view-projection (reverse-Z)
    inv_view_proj: mat4x4<f32>,  // its inverse
    eye: vec4<f32>,              // eye position in world metres (x, y, z), w unused
    sun: vec4<f32>,              // unit vector towards the sun, w unused
    fog: vec4<f32>,              // x fog start (m), y fog end (m), z water level (m), w terrain amplitude (m)
    params: vec4<f32>,           // x: colour nodes by depth (0/1), y: time (s), z: full shading (0 plain / 1)
    shadow: array<mat4x4<f32>, 2>, // camera-relative metres to each shadow cascade's clip space
    shadow_info: vec4<f32>,      // x: near cascade's far end (m), y: far cascade's (m), z, w: their texel sizes (m)
};

@group(0) @binding(0) var<uniform> g: Globals;
@group(0) @binding(1) var shadow_map: texture_depth_2d_array;
@group(0) @binding(2) var shadow_sampler: sampler_comparison;

// Whether the fragment shaders write sRGB-encoded values (a plain 8-bit target, where the
// device has no sRGB views: WebGL2) instead of linear ones (an sRGB target the GPU encodes).
override ENCODE_SRGB: bool = false;

// The sRGB transfer function (IEC 61966-2-1) of linear values in 0..1.
fn srgb_encode(c: vec3<f32>) -> vec3<f32> {
    let l = clamp(c, vec3<f32>(0.0), vec3<f32>(1.0));
    let hi = 1.055 * pow(l, vec3<f32>(1.0 / 2.4)) - 0.055;
    return select(hi, l * 12.92, l <= vec3<f32>(0.0031308));
}

// A fragment's linear colour as the view's target stores it.
fn to_target(c: vec4<f32>) -> vec4<f32> {
    if ENCODE_SRGB {
        return vec4<f32>(srgb_encode(c.rgb), c.a);
    }
    return c;
}

fn full_shading() -> bool {
    return g.params.z > 0.5;
}

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

// The water's colour seen along `rel` (camera-relative metres) on a level surface: the sky
// reflected with a Fresnel term over a deep tone, small analytic ripples, the sun's glint.
// Returns the colour and the Fresnel term (the water plane's opacity follows it).
fn water_colour(rel: vec3<f32>) -> vec4<f32> {
    let view = normalize(rel);
    // Four wave trains in unaligned directions and lengths (200 m down to 55 m), so the
    // surface shows no grid; fading with distance, where they would only alias.
    let w = rel.xz + g.eye.xz;
    let t = g.params.y;
    let d1 = vec2<f32>(0.82, 0.57);
    let d2 = vec2<f32>(-0.38, 0.92);
    let d3 = vec2<f32>(0.96, -0.28);
    let d4 = vec2<f32>(-0.71, -0.70);
    var ripple = d1 * cos(dot(d1, w) * 0.031 + t * 0.7) * 0.8;
    ripple += d2 * cos(dot(d2, w) * 0.047 - t * 0.9) * 0.6;
    ripple += d3 * cos(dot(d3, w) * 0.071 + t * 1.2) * 0.45;
    ripple += d4 * cos(dot(d4, w) * 0.113 - t * 1.5) * 0.3;
    ripple *= 0.02 * clamp(1.0 - length(rel) / 4000.0, 0.2, 1.0);
    let n = normalize(vec3<f32>(ripple.x, 1.0, ripple.y));
    let r = reflect(view, n);
    let fresnel = 0.04 + 0.96 * pow(1.0 - max(dot(-view, n), 0.0), 5.0);
    let deep = vec3<f32>(0.03, 0.12, 0.20);
    var c = mix(deep, sky_colour(r), fresnel);
    c += vec3<f32>(1.0, 0.9, 0.7) * pow(max(dot(r, g.sun.xyz), 0.0), 400.0) * 3.0;
    return vec4<f32>(c, fresnel);
}

// Aerial perspective: haze whose density falls off with height (scale height 1.6 km above the
// water level), so distant valleys fade and summits stay clear; in-scattered light is the sky's
// horizon tone, warmer towards the sun. The optical depth is integrated along the view ray in
// closed form. At the view's far end the sky itself takes over (as `apply_fog`).
fn aerial(c: vec3<f32>, rel: vec3<f32>) -> vec3<f32> {
    let d = length(rel);
    let view = rel / max(d, 1e-3);
    let scale_h = 1600.0;
    let density = 1.0 / 42000.0; // extinction per metre at the water level
    let h0 = (g.eye.y - g.fog.z) / scale_h;
    let dh = rel.y / scale_h;
    var depth = density * d * exp(-max(h0, -2.0));
    if (abs(dh) > 1e-3) {
        depth = density * d * (exp(-max(h0, -2.0)) - exp(-max(h0 + dh, -2.0))) / dh;
    }
    let t = exp(-depth);
    let sun_side = pow(max(dot(view, g.sun.xyz), 0.0), 6.0);
    // The haze's own light: the sky's gradient near the horizon (without the sun's disc).
    let up = clamp(view.y, 0.0, 1.0);
    let horizon = mix(vec3<f32>(0.68, 0.78, 0.90), vec3<f32>(0.16, 0.36, 0.72), sqrt(up) * 0.9);
    let haze = mix(horizon * 0.95, vec3<f32>(0.98, 0.86, 0.68), sun_side * 0.45);
    let hazed = mix(haze, c, t);
    let e = clamp((d - g.fog.y * 0.7) / max(g.fog.y * 0.3, 1.0), 0.0, 1.0);
    if (e <= 0.0) {
        return hazed;
    }
    let sky = sky_colour(view);
    return mix(hazed, sky, e * e * (3.0 - 2.0 * e));
}

// The plain shading's fog: one haze from `g.fog.x` to `g.fog.y` metres, the sky at its end.
fn apply_fog(c: vec3<f32>, rel: vec3<f32>) -> vec3<f32> {
    let d = length(rel);
    let t = clamp((d - g.fog.x) / max(g.fog.y - g.fog.x, 1.0), 0.0, 1.0);
    let f = t * t * (3.0 - 2.0 * t);
    // The sky drawn behind it in the same direction: where the fog is whole (the far field's
    // edge) the terrain is exactly the sky beside it, so no edge shows, from any height.
    let haze = sky_colour(normalize(rel));
    return mix(c, haze, f);
}
