// Shared by the rasterizer kernels: the splat layout, the constants of SPEC §4 and the
// Gaussian falloff, written to agree with the CPU reference (src/raster/) pixel for pixel.

const TILE: u32 = 16u;
const TILE_PIXELS: u32 = 256u;
const ALPHA_MIN: f32 = 0.003921569; // 1/255
const ALPHA_MAX: f32 = 0.99;
const TRANSMITTANCE_MIN: f32 = 1e-4;

// A projected Gaussian. `conic.w` is the exponent below which alpha < 1/255 (computed on the
// CPU with the reference's formula); `color.w` is the opacity.
struct Splat {
    mean: vec2<f32>,
    extent: vec2<f32>,
    conic: vec4<f32>,
    color: vec4<f32>,
}

struct Params {
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    background: vec4<f32>,
}

// e^x for x ≤ 0 by the reference's power-of-two split and degree-6 polynomial, so GPU and CPU
// agree to rounding (WGSL's exp has implementation-defined precision).
fn exp_falloff(x: f32) -> f32 {
    let t = max(x * 1.442695041, -126.0);
    let n = round(t);
    let f = t - n;
    let p = 1.0 + f * (0.6931472 + f * (0.2402265 + f * (0.05550411
        + f * (0.009618129 + f * (0.0013333558 + f * 0.0001540353)))));
    return bitcast<f32>(u32(i32(n) + 127) << 23u) * p;
}

// (dx, dy, G, drawn) of splat `s` at tile-local pixel `local` of the tile at `origin`: drawn is
// 1 inside the splat's screen box where opacity·G ≥ 1/255, as in the reference's `falloff_at`.
fn falloff_at(s: Splat, origin: vec2<u32>, local: vec2<u32>) -> vec4<f32> {
    let o = vec2<f32>(origin);
    let l = vec2<f32>(local);
    let lo = floor(s.mean - s.extent - 0.5 - o);
    let hi = ceil(s.mean + s.extent - 0.5 - o);
    if any(l < lo) || any(l > hi) {
        return vec4<f32>(0.0);
    }
    let d = vec2<f32>(origin + local) + 0.5 - s.mean;
    let pw = -0.5 * (s.conic.x * d.x * d.x + s.conic.z * d.y * d.y) - s.conic.y * d.x * d.y;
    if pw > 0.0 || pw < s.conic.w {
        return vec4<f32>(0.0);
    }
    let g = exp_falloff(pw);
    if s.color.w * g < ALPHA_MIN {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(d, g, 1.0);
}
