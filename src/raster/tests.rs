use glam::Vec2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;

const W: usize = 37;
const H: usize = 29;

fn random_splats(rng: &mut ChaCha8Rng, n: usize) -> Vec<Splat> {
    (0..n)
        .map(|_| {
            let sx: f32 = rng.random_range(12.0..20.0);
            let sy: f32 = rng.random_range(12.0..20.0);
            let rho: f32 = rng.random_range(-0.5..0.5);
            let (xx, yy, xy) = (sx * sx, sy * sy, rho * sx * sy);
            let det = xx * yy - xy * xy;
            Splat {
                mean2d: Vec2::new(rng.random_range(13.0..24.0), rng.random_range(10.0..19.0)),
                conic: [yy / det, -xy / det, xx / det],
                depth: rng.random_range(1.0..5.0),
                opacity: rng.random_range(0.25..0.6),
                color: [rng.random(), rng.random(), rng.random()],
                extent: Vec2::new(3.4 * sx, 3.4 * sy),
                visible: true,
            }
        })
        .collect()
}

/// Loss = Σ weight·colour over the image, so dL/dcolour = weight.
fn weighted_sum(
    raster: &mut Rasterizer,
    splats: &[Splat],
    weights: &[[f32; 3]],
    bg: [f32; 3],
) -> f64 {
    let mut out = RenderOutput::default();
    raster.forward(splats, W, H, bg, &mut out);
    out.image
        .data
        .iter()
        .zip(weights)
        .map(|(c, w)| (0..3).map(|i| (c[i] * w[i]) as f64).sum::<f64>())
        .sum()
}

#[test]
fn opaque_splat_covers_its_centre_and_background_shows_elsewhere() {
    let splat = Splat {
        mean2d: Vec2::new(10.5, 10.5),
        conic: [1.0 / 4.0, 0.0, 1.0 / 4.0],
        depth: 1.0,
        opacity: 1.0,
        color: [1.0, 0.0, 0.0],
        extent: Vec2::splat(7.0),
        visible: true,
    };
    let mut raster = Rasterizer::new();
    let mut out = RenderOutput::default();
    raster.forward(&[splat], W, H, [0.0, 0.0, 1.0], &mut out);
    let centre = out.image.data[10 * W + 10];
    // α clamps at 0.99 at the centre: 0.99 red + 0.01 background blue.
    assert!((centre[0] - 0.99).abs() < 1e-5 && (centre[2] - 0.01).abs() < 1e-5);
    assert!((out.alpha[10 * W + 10] - 0.99).abs() < 1e-5);
    assert_eq!(out.image.data[(H - 1) * W + W - 1], [0.0, 0.0, 1.0]);
}

#[test]
fn nearer_splat_occludes_farther_one() {
    let mut near = Splat {
        mean2d: Vec2::new(16.0, 16.0),
        conic: [0.1, 0.0, 0.1],
        depth: 1.0,
        opacity: 0.99,
        color: [1.0, 0.0, 0.0],
        extent: Vec2::splat(10.0),
        visible: true,
    };
    let mut far = near;
    far.depth = 2.0;
    far.color = [0.0, 1.0, 0.0];
    let mut raster = Rasterizer::new();
    let mut out = RenderOutput::default();
    // Order in the input must not matter: the sort is by depth.
    raster.forward(&[far, near], W, H, [0.0; 3], &mut out);
    let c = out.image.data[15 * W + 15];
    assert!(c[0] > 0.95 && c[1] < 0.05, "{c:?}");
    near.depth = 3.0;
    raster.forward(&[far, near], W, H, [0.0; 3], &mut out);
    let c = out.image.data[15 * W + 15];
    assert!(c[1] > 0.95 && c[0] < 0.05, "{c:?}");
}

/// The analytic gradient of every splat field matches central finite differences of the
/// whole render (f64 accumulation of an f32 render; relative error ≤ 2e-3 with an absolute
/// floor of 1e-3·max|grad| for entries near zero, where f32 rounding in the image dominates).
///
/// The splats are wide (σ 12–20 px) and semi-transparent so that every pixel of the image is
/// above the 1/255 alpha cut-off and above the transmittance cut-off: those cut-offs are
/// discontinuities that a finite difference cannot see through.
#[test]
fn backward_matches_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let splats = random_splats(&mut rng, 6);
    let weights: Vec<[f32; 3]> = (0..W * H)
        .map(|_| [rng.random(), rng.random(), rng.random()])
        .collect();
    let bg = [0.2, 0.4, 0.6];
    let mut raster = Rasterizer::new();
    weighted_sum(&mut raster, &splats, &weights, bg);
    let mut grads = Vec::new();
    raster.backward(&splats, &weights, W, &mut grads);

    let mut checked = 0;
    for s in 0..splats.len() {
        type Field = (&'static str, fn(&mut Splat) -> &mut f32, f32);
        let fields: [Field; 9] = [
            ("mean.x", |s| &mut s.mean2d.x, 1e-2),
            ("mean.y", |s| &mut s.mean2d.y, 1e-2),
            ("conic.a", |s| &mut s.conic[0], 1e-4),
            ("conic.b", |s| &mut s.conic[1], 1e-4),
            ("conic.c", |s| &mut s.conic[2], 1e-4),
            ("opacity", |s| &mut s.opacity, 1e-3),
            ("r", |s| &mut s.color[0], 1e-2),
            ("g", |s| &mut s.color[1], 1e-2),
            ("b", |s| &mut s.color[2], 1e-2),
        ];
        let g = grads[s];
        let analytic = [
            g.mean2d.x, g.mean2d.y, g.conic[0], g.conic[1], g.conic[2], g.opacity, g.color[0],
            g.color[1], g.color[2],
        ];
        let scale = analytic.iter().fold(0f32, |m, v| m.max(v.abs()));
        for (i, (name, field, h)) in fields.iter().enumerate() {
            let mut plus = splats.clone();
            *field(&mut plus[s]) += h;
            let mut minus = splats.clone();
            *field(&mut minus[s]) -= h;
            let fd = (weighted_sum(&mut raster, &plus, &weights, bg)
                - weighted_sum(&mut raster, &minus, &weights, bg))
                / (2.0 * *h as f64);
            let a = analytic[i] as f64;
            let err = (a - fd).abs();
            let tol = 2e-3 * a.abs().max(fd.abs()) + 1e-3 * scale as f64;
            assert!(err <= tol, "splat {s} {name}: analytic {a} fd {fd}");
            checked += 1;
        }
    }
    assert_eq!(checked, 6 * 9);
}

/// The fast falloff exponential matches `f32::exp` to 2e-6 relative over the range that matters (the limit is
/// the f32 rounding of x·log2(e), ≈ 1e-6 at x = −20)
/// (down to e^-20, far below the 1/255 alpha cut-off).
#[test]
fn exp_falloff_matches_exp() {
    let mut worst = 0f64;
    for i in 0..=200_000 {
        let x = -20.0 * i as f32 / 200_000.0;
        let exact = (x as f64).exp();
        worst = worst.max(((exp_falloff(x) as f64) - exact).abs() / exact);
    }
    assert!(worst < 2e-6, "worst relative error {worst:e}");
    assert_eq!(exp_falloff(0.0), 1.0);
    assert!(exp_falloff(-200.0) < 1e-37);
}
