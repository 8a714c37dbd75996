//! The GPU rasterizer (forward and backward blending) equals the CPU reference on random
//! splat populations.

#[path = "common/gpu.rs"]
mod gpu;

use glam::Vec2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tadgs::gpu::{GpuContext, GpuRasterizer};
use tadgs::raster::{Rasterizer, RenderOutput, Splat, SplatGrad};

/// Random splats over a `width × height` image: sizes from sub-pixel to a quarter of the
/// image, anisotropic with correlations up to ±`max_rho` (near 1: thin slanted ellipses, far
/// smaller than their boxes), opacities from 0.02 to `max_opacity` (above 1: some clamped at
/// 0.99), some off screen or invisible.
fn random_splats(
    rng: &mut ChaCha8Rng,
    n: usize,
    (width, height): (f32, f32),
    max_rho: f32,
    max_opacity: f32,
) -> Vec<Splat> {
    (0..n)
        .map(|_| {
            let sx: f32 = rng.random_range(0.5..width / 8.0);
            let sy: f32 = rng.random_range(0.5..height / 8.0);
            let rho: f32 = rng.random_range(-max_rho..max_rho);
            let (xx, yy, xy) = (sx * sx + 0.3, sy * sy + 0.3, rho * sx * sy);
            let det = xx * yy - xy * xy;
            let opacity = rng.random_range(0.02..max_opacity).min(1.0);
            let radius = (2.0 * (255.0 * opacity).ln()).max(0.0).sqrt();
            Splat {
                mean2d: Vec2::new(
                    rng.random_range(-10.0..width + 10.0),
                    rng.random_range(-10.0..height + 10.0),
                ),
                conic: [yy / det, -xy / det, xx / det],
                depth: rng.random_range(0.5..10.0),
                opacity,
                color: [rng.random(), rng.random(), rng.random()],
                extent: Vec2::new(radius * xx.sqrt(), radius * yy.sqrt()),
                visible: rng.random_bool(0.95),
            }
        })
        .collect()
}

/// Largest |a − b| / (|b| + floor) over paired values.
fn worst_relative(a: impl Iterator<Item = f32>, b: impl Iterator<Item = f32>, floor: f32) -> f32 {
    a.zip(b)
        .map(|(x, y)| (x - y).abs() / (y.abs() + floor))
        .fold(0.0, f32::max)
}

fn grad_fields(g: &SplatGrad) -> [f32; 9] {
    [
        g.mean2d.x, g.mean2d.y, g.conic[0], g.conic[1], g.conic[2], g.opacity, g.color[0],
        g.color[1], g.color[2],
    ]
}

/// The portable backward (per-tile partial sums, no float atomics): the path for adapters
/// without SHADER_FLOAT32_ATOMIC (wgpu's GL backend, Metal, many DX12 drivers).
#[test]
fn gpu_raster_with_tile_sums_equals_cpu_reference() {
    let Some(mut gpu) = gpu::gpu_rasterizer(GpuRasterizer::portable) else {
        return;
    };
    assert!(!gpu.uses_float_atomics());
    assert_parity(&mut gpu);
}

/// The default rasterizer: the float-atomic backward where the adapter offers it (lavapipe
/// does), else the same portable path as above.
#[test]
fn gpu_raster_default_equals_cpu_reference() {
    let Some(mut gpu) = gpu::gpu_rasterizer(GpuRasterizer::new) else {
        return;
    };
    assert_parity(&mut gpu);
}

/// Every layout of the blending kernels (pixels of a tile column per invocation: hardware GPUs
/// take 1, software adapters 8) equals the CPU reference, with either backward.
#[test]
fn gpu_raster_every_pixel_layout_equals_cpu_reference() {
    for float_atomics in [true, false] {
        for rows in [1, 2, 4, 16] {
            let Some(context) = gpu::open_or_skip(|| GpuContext::new(float_atomics)) else {
                return;
            };
            assert_parity(&mut GpuRasterizer::with_pixel_rows(context, rows));
        }
    }
}

/// Forward: every pixel's colour and alpha equal the CPU's to 1e-4 relative (values are in
/// [0, 1]; floor 1e-2 so near-black pixels are held to 1e-6 absolute), for image sizes that
/// are and are not multiples of the 16-pixel tile and for populations from 1 to 3000 splats.
/// Backward: every field of every splat's gradient equals the CPU's to 1e-4 relative, with an
/// absolute floor of 1e-4 × the largest gradient of that field: the two backends add the same
/// shares in a different order (tree, atomics or sequential), so entries that cancel to near zero
/// differ by rounding of the large ones.
fn assert_parity(gpu: &mut GpuRasterizer) {
    eprintln!("adapter: {}", gpu.describe());
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut cpu = Rasterizer::new();
    // The fifth scene's thin slanted ellipses test that the GPU kernels' cull of tile segments
    // outside each ellipse (`segments_reached` in shaders/raster_common.wgsl) skips no pixel
    // that draws; the last scene's faint splats keep pixels open through several batches of
    // 256 entries per tile (an entry index that loses its batch's offset fails only there).
    for (width, height, n, max_rho, max_opacity) in [
        (64, 48, 1, 0.8, 1.2),
        (77, 53, 300, 0.8, 1.2),
        (160, 120, 3000, 0.8, 1.2),
        (33, 200, 500, 0.8, 1.2),
        (96, 80, 800, 0.995, 1.2),
        (32, 32, 4000, 0.8, 0.05),
    ] {
        let size = (width as f32, height as f32);
        let splats = random_splats(&mut rng, n, size, max_rho, max_opacity);
        let background = [rng.random(), rng.random(), rng.random()];
        let (mut out_cpu, mut out_gpu) = (RenderOutput::default(), RenderOutput::default());
        cpu.forward(&splats, width, height, background, &mut out_cpu);
        gpu.forward(&splats, width, height, background, &mut out_gpu)
            .unwrap();
        assert_eq!(gpu.intersections(), cpu.intersections());
        assert_eq!((out_gpu.image.width, out_gpu.image.height), (width, height));
        let flat = |o: &RenderOutput| -> Vec<f32> {
            o.image
                .data
                .iter()
                .flatten()
                .copied()
                .chain(o.alpha.iter().copied())
                .collect()
        };
        let image_err =
            worst_relative(flat(&out_gpu).into_iter(), flat(&out_cpu).into_iter(), 1e-2);
        assert!(
            image_err <= 1e-4,
            "{width}×{height}, {n} splats: image differs by {image_err:e} relative"
        );

        let d_color: Vec<[f32; 3]> = (0..width * height)
            .map(|_| [0; 3].map(|_| rng.random_range(-1.0..1.0)))
            .collect();
        let (mut g_cpu, mut g_gpu) = (Vec::new(), Vec::new());
        cpu.backward(&splats, &d_color, width, &mut g_cpu);
        gpu.backward(&splats, &d_color, &mut g_gpu).unwrap();
        assert_eq!(g_gpu.len(), splats.len());
        for field in 0..9 {
            let largest = g_cpu
                .iter()
                .fold(0f32, |m, g| m.max(grad_fields(g)[field].abs()));
            for (s, (g, c)) in g_gpu.iter().zip(&g_cpu).enumerate() {
                let (g, c) = (grad_fields(g)[field], grad_fields(c)[field]);
                assert!(
                    (g - c).abs() <= 1e-4 * c.abs() + 1e-4 * largest,
                    "{width}×{height}, {n} splats: splat {s} field {field}: GPU {g} vs CPU {c}"
                );
            }
        }
    }
}
