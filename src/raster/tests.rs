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

/// Straightforward per-pixel forward: every pixel walks all splats in depth order (ties by
/// index) with the same falloff, cut-offs and blending; no tiles, no binning, no lane groups.
/// Returns the image, final transmittance and, per pixel, the splats blended into it.
fn reference_forward(
    splats: &[Splat],
    w: usize,
    h: usize,
    bg: [f32; 3],
) -> (Vec<[f32; 3]>, Vec<f32>, Vec<Vec<usize>>) {
    let mut order: Vec<usize> = (0..splats.len()).filter(|&s| splats[s].visible).collect();
    order.sort_by(|&i, &j| splats[i].depth.total_cmp(&splats[j].depth).then(i.cmp(&j)));
    let mut image = vec![[0f32; 3]; w * h];
    let mut final_t = vec![1f32; w * h];
    let mut blended = vec![Vec::new(); w * h];
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            let mut t = 1f32;
            for &s in &order {
                let Some((_, _, alpha)) = reference_alpha(&splats[s], x, y) else {
                    continue;
                };
                let next = t * (1.0 - alpha);
                if next < TRANSMITTANCE_MIN {
                    break;
                }
                for c in 0..3 {
                    image[p][c] += splats[s].color[c] * alpha * t;
                }
                t = next;
                blended[p].push(s);
            }
            final_t[p] = t;
            for c in 0..3 {
                image[p][c] += t * bg[c];
            }
        }
    }
    (image, final_t, blended)
}

/// Gaussian falloff exponent at offset (dx, dy) from the centre, as SPEC §4 writes it.
fn power(conic: &[f32; 3], dx: f32, dy: f32) -> f32 {
    -0.5 * (conic[0] * dx * dx + conic[2] * dy * dy) - conic[1] * dx * dy
}

/// (dx, dy, alpha) of a splat at pixel (x, y), or None where it is not drawn.
fn reference_alpha(sp: &Splat, x: usize, y: usize) -> Option<(f32, f32, f32)> {
    let dx = x as f32 + 0.5 - sp.mean2d.x;
    let dy = y as f32 + 0.5 - sp.mean2d.y;
    // Outside the screen box (one pixel of slack) alpha < 1/255 by construction.
    if dx.abs() > sp.extent.x + 1.0 || dy.abs() > sp.extent.y + 1.0 {
        return None;
    }
    let power = power(&sp.conic, dx, dy);
    if power > 0.0 || power < min_power(sp.opacity) {
        return None;
    }
    let raw = sp.opacity * exp_falloff(power);
    (raw >= ALPHA_MIN).then_some((dx, dy, raw.min(ALPHA_MAX)))
}

/// Per-pixel backward of [`reference_forward`]: each pixel walks its blended splats back to
/// front; sums in f64.
fn reference_backward(
    splats: &[Splat],
    w: usize,
    bg: [f32; 3],
    d_color: &[[f32; 3]],
    final_t: &[f32],
    blended: &[Vec<usize>],
) -> Vec<[f64; 9]> {
    let mut grads = vec![[0f64; 9]; splats.len()];
    for (p, list) in blended.iter().enumerate() {
        let (x, y) = (p % w, p / w);
        let d = d_color[p];
        let bg_dot: f32 = (0..3).map(|c| bg[c] * d[c]).sum();
        let mut t = final_t[p];
        let mut behind = [0f32; 3];
        for &s in list.iter().rev() {
            let sp = &splats[s];
            let (dx, dy, alpha) = reference_alpha(sp, x, y).unwrap();
            t /= 1.0 - alpha;
            let g = &mut grads[s];
            let mut d_alpha = 0.0;
            for c in 0..3 {
                d_alpha += (sp.color[c] - behind[c]) * d[c];
                g[6 + c] += (alpha * t * d[c]) as f64;
            }
            d_alpha = d_alpha * t - final_t[p] / (1.0 - alpha) * bg_dot;
            for c in 0..3 {
                behind[c] = alpha * sp.color[c] + (1.0 - alpha) * behind[c];
            }
            let raw = sp.opacity * exp_falloff(power(&sp.conic, dx, dy));
            if raw >= ALPHA_MAX {
                continue;
            }
            let gauss = raw / sp.opacity;
            let d_power = (raw * d_alpha) as f64;
            let [a, b, c] = sp.conic.map(|v| v as f64);
            let (dx, dy) = (dx as f64, dy as f64);
            g[0] += d_power * (a * dx + b * dy);
            g[1] += d_power * (c * dy + b * dx);
            g[2] -= 0.5 * dx * dx * d_power;
            g[3] -= dx * dy * d_power;
            g[4] -= 0.5 * dy * dy * d_power;
            g[5] += (gauss * d_alpha) as f64;
        }
    }
    grads
}

/// Many overlapping splats of every size (σ 0.4–25 px), shape, opacity (some clamped at 0.99)
/// and depth, some partly off screen, on an image that is not a whole number of tiles.
fn crowded_scene(rng: &mut ChaCha8Rng, n: usize, w: usize, h: usize) -> Vec<Splat> {
    (0..n)
        .map(|i| {
            let sx: f32 = rng.random_range(0.4f32..25.0);
            let sy: f32 = sx * rng.random_range(0.1f32..1.0);
            let angle: f32 = rng.random_range(0.0..std::f32::consts::PI);
            let (sin, cos) = angle.sin_cos();
            let xx = cos * cos * sx * sx + sin * sin * sy * sy;
            let yy = sin * sin * sx * sx + cos * cos * sy * sy;
            let xy = cos * sin * (sx * sx - sy * sy);
            let det = xx * yy - xy * xy;
            let opacity: f32 = rng.random_range(0.05..1.0);
            let radius = (2.0 * (255.0 * opacity).ln()).max(0.0).sqrt();
            Splat {
                mean2d: Vec2::new(
                    rng.random_range(-10.0..w as f32 + 10.0),
                    rng.random_range(-10.0..h as f32 + 10.0),
                ),
                conic: [yy / det, -xy / det, xx / det],
                // Every tenth splat shares a depth with its neighbour: ties go by index.
                depth: if i % 10 == 1 {
                    1.0
                } else {
                    rng.random_range(1.0..5.0)
                },
                opacity,
                color: [rng.random(), rng.random(), rng.random()],
                extent: Vec2::new(radius * xx.sqrt(), radius * yy.sqrt()),
                visible: i % 17 != 3,
            }
        })
        .collect()
}

/// The tiled, vectorised rasterizer gives the per-pixel reference's image, alpha and splat
/// gradients on a crowded scene where most pixels stop early (transmittance cut-off), many
/// splats are clipped by the image border and some alphas clamp at 0.99.
#[test]
fn tiled_rasterizer_matches_per_pixel_reference() {
    let (w, h) = (83, 45);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let splats = crowded_scene(&mut rng, 400, w, h);
    let bg = [0.1, 0.3, 0.2];
    let mut raster = Rasterizer::new();
    let mut out = RenderOutput::default();
    raster.forward(&splats, w, h, bg, &mut out);
    let (image, final_t, blended) = reference_forward(&splats, w, h, bg);
    let stopped = final_t.iter().filter(|&&t| t < 2e-3).count();
    assert!(
        stopped > w * h / 4,
        "the scene must exercise early stopping: {stopped}"
    );
    for p in 0..w * h {
        for c in 0..3 {
            assert!(
                (out.image.data[p][c] - image[p][c]).abs() < 1e-5,
                "pixel {p}: {:?} vs {:?}",
                out.image.data[p],
                image[p]
            );
        }
        assert!(
            (out.alpha[p] - (1.0 - final_t[p])).abs() < 1e-6,
            "alpha at {p}"
        );
    }

    let d_color: Vec<[f32; 3]> = (0..w * h)
        .map(|_| [(); 3].map(|_| rng.random_range(-1.0..1.0)))
        .collect();
    let mut grads = Vec::new();
    raster.backward(&splats, &d_color, w, &mut grads);
    let reference = reference_backward(&splats, w, bg, &d_color, &final_t, &blended);
    for (s, (g, r)) in grads.iter().zip(&reference).enumerate() {
        let got = [
            g.mean2d.x, g.mean2d.y, g.conic[0], g.conic[1], g.conic[2], g.opacity, g.color[0],
            g.color[1], g.color[2],
        ];
        let scale = r.iter().fold(1e-3f64, |m, v| m.max(v.abs()));
        for i in 0..9 {
            assert!(
                (got[i] as f64 - r[i]).abs() <= 1e-4 * scale,
                "splat {s} entry {i}: {} vs {}",
                got[i],
                r[i]
            );
        }
    }
    // Invisible splats get no gradient.
    assert!(grads[3] == SplatGrad::default());
}

/// The tiles [x0, x1) × [y0, y1) that a splat's screen box overlaps, by definition, as
/// (x0, y0, x1, y1).
fn tile_rectangle(s: &Splat, tiles_x: usize, tiles_y: usize) -> (usize, usize, usize, usize) {
    let t = TILE as f32;
    let lo = (s.mean2d - s.extent) / t;
    let hi = (s.mean2d + s.extent) / t;
    let x0 = lo.x.floor().clamp(0.0, tiles_x as f32) as usize;
    let y0 = lo.y.floor().clamp(0.0, tiles_y as f32) as usize;
    let x1 = (hi.x.floor() + 1.0).clamp(0.0, tiles_x as f32) as usize;
    let y1 = (hi.y.floor() + 1.0).clamp(0.0, tiles_y as f32) as usize;
    (x0, y0, x1, y1)
}

/// Binning equals the definition (every visible splat in every tile its screen box overlaps,
/// ordered by depth then index, and `sorted_position` pointing each (splat, tile) pair at its
/// entry) for image sizes with partial tiles or none, and for enough splats (40 000) that they
/// are cut into several chunks binned in parallel.
#[test]
fn binning_matches_naive_per_tile_lists() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for (w, h, n) in [
        (37, 29, 300),
        (83, 45, 300),
        (200, 75, 300),
        (16, 200, 300),
        (333, 17, 300),
        (0, 40, 300),
        (40, 0, 300),
        (83, 45, 40_000),
    ] {
        let mut splats = crowded_scene(&mut rng, n, w, h);
        // Equal depths exercise the index tie-break.
        for s in splats.iter_mut().step_by(7) {
            s.depth = 2.0;
        }
        let mut bins = TileBins::default();
        bins.build(&splats, w, h);
        let (tiles_x, tiles_y) = (w.div_ceil(TILE), h.div_ceil(TILE));
        let rect = |s: &Splat| tile_rectangle(s, tiles_x, tiles_y);
        for ty in 0..tiles_y {
            for tx in 0..tiles_x {
                let mut expected: Vec<usize> = (0..splats.len())
                    .filter(|&i| {
                        let (x0, y0, x1, y1) = rect(&splats[i]);
                        splats[i].visible && (x0..x1).contains(&tx) && (y0..y1).contains(&ty)
                    })
                    .collect();
                expected
                    .sort_by(|&a, &b| splats[a].depth.total_cmp(&splats[b].depth).then(a.cmp(&b)));
                let tile = ty * tiles_x + tx;
                let got: Vec<usize> = bins.sorted_splats[bins.tile_range(tile)]
                    .iter()
                    .map(|&s| s as usize)
                    .collect();
                assert_eq!(got, expected, "{w}×{h}, tile ({tx}, {ty})");
            }
        }
        let sorted_position = bins.sorted_position().to_vec();
        for s in 0..splats.len() {
            for e in bins.splat_range(s) {
                assert_eq!(bins.sorted_splats[sorted_position[e] as usize] as usize, s);
            }
            let (x0, y0, x1, y1) = rect(&splats[s]);
            let covered = if splats[s].visible {
                (x1.saturating_sub(x0)) * (y1.saturating_sub(y0))
            } else {
                0
            };
            assert_eq!(bins.splat_range(s).len(), covered, "{w}×{h}, splat {s}");
        }
    }
}

/// The pair counts of `tadgs bench` equal a count made pixel by pixel: every visible splat whose
/// tile rectangle holds the pixel's tile and whose screen box holds the pixel, in depth order,
/// evaluated while the pixel still blends and blended when its alpha reaches 1/255.
#[test]
fn pair_counts_match_a_per_pixel_count() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (w, h) = (83, 45);
    let splats = crowded_scene(&mut rng, 400, w, h);
    let mut raster = Rasterizer::new();
    raster.forward(&splats, w, h, [0.0; 3], &mut RenderOutput::default());
    let (tiles_x, tiles_y) = (w.div_ceil(TILE), h.div_ceil(TILE));
    let mut order: Vec<usize> = (0..splats.len()).filter(|&i| splats[i].visible).collect();
    order.sort_by(|&a, &b| splats[a].depth.total_cmp(&splats[b].depth).then(a.cmp(&b)));
    let mut expected = PairCounts::default();
    for (px, py) in (0..h).flat_map(|y| (0..w).map(move |x| (x, y))) {
        let (tx, ty) = (px / TILE, py / TILE);
        let origin = (tx * TILE, ty * TILE);
        let mut transmittance = 1f32;
        for &i in &order {
            let s = &splats[i];
            let (rx0, ry0, rx1, ry1) = tile_rectangle(s, tiles_x, tiles_y);
            let in_rect = (rx0..rx1).contains(&tx) && (ry0..ry1).contains(&ty);
            let [x0, x1, y0, y1] = box_in_tile(s.mean2d.to_array(), s.extent.to_array(), origin);
            let (x, y) = (px - origin.0, py - origin.1);
            if !in_rect || !(x0..x1).contains(&x) || !(y0..y1).contains(&y) {
                continue;
            }
            expected.evaluated += 1;
            let d = Vec2::new(px as f32 + 0.5, py as f32 + 0.5) - s.mean2d;
            let power = power(&s.conic, d.x, d.y);
            let alpha = (s.opacity * power.exp()).min(ALPHA_MAX);
            if power > 0.0 || alpha < ALPHA_MIN {
                continue;
            }
            if transmittance * (1.0 - alpha) < TRANSMITTANCE_MIN {
                break;
            }
            transmittance *= 1.0 - alpha;
            expected.blended += 1;
        }
    }
    let counts = raster.pair_counts(w, h);
    assert!(counts.blended > 10_000 && counts.evaluated > counts.blended);
    assert_eq!(counts, expected);
}

/// A reused rasterizer gives exactly the gradients of a fresh one: buffers left over from an
/// earlier, larger frame (entries never walked this time) are never read.
#[test]
fn reused_rasterizer_backward_equals_fresh_one() {
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let (w, h) = (83, 45);
    let first = crowded_scene(&mut rng, 900, w, h);
    let second = crowded_scene(&mut rng, 300, w, h);
    let bg = [0.2, 0.1, 0.4];
    let d_color: Vec<[f32; 3]> = (0..w * h)
        .map(|_| [(); 3].map(|_| rng.random_range(-1.0..1.0)))
        .collect();
    let mut out = RenderOutput::default();
    let mut reused = Rasterizer::new();
    let mut grads = Vec::new();
    reused.forward(&first, w, h, bg, &mut out);
    reused.backward(&first, &d_color, w, &mut grads);
    reused.forward(&second, w, h, bg, &mut out);
    reused.backward(&second, &d_color, w, &mut grads);
    let mut fresh = Rasterizer::new();
    let mut expected = Vec::new();
    fresh.forward(&second, w, h, bg, &mut out);
    fresh.backward(&second, &d_color, w, &mut expected);
    assert_eq!(grads, expected);
}

/// The kernels follow the CPU: the best level it has (AVX-512 where it has AVX-512 F, VL, BW
/// and DQ besides AVX2 and FMA; AVX2 where it has AVX2 and FMA), unless `TADGS_SIMD` asks for a
/// lower one (as in the child processes of [`lower_level_kernels_match_the_reference`]).
#[test]
fn simd_level_follows_the_environment() {
    #[cfg(target_arch = "x86_64")]
    let (avx2, avx512) = (
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"),
        is_x86_feature_detected!("avx512f")
            && is_x86_feature_detected!("avx512vl")
            && is_x86_feature_detected!("avx512bw")
            && is_x86_feature_detected!("avx512dq"),
    );
    #[cfg(not(target_arch = "x86_64"))]
    let (avx2, avx512) = (false, false);
    let best = match (avx2, avx512) {
        (true, true) => "x86-64 AVX-512 + FMA",
        (true, false) => "x86-64 AVX2 + FMA",
        _ => "baseline",
    };
    let expected = match std::env::var("TADGS_SIMD").as_deref() {
        Ok("baseline") => "baseline",
        Ok("avx2") if avx2 => "x86-64 AVX2 + FMA",
        _ => best,
    };
    assert_eq!(simd_level().name(), expected);
}

/// The kernels of every level below the one this CPU runs (the baseline ones without AVX2 or
/// fused multiply-adds, and the AVX2 ones where the CPU has AVX-512) pass the reference and
/// finite-difference tests of the rasterizer and the SSIM too. The kernel choice is made once
/// per process, so those tests run again in child processes of this test binary with
/// `TADGS_SIMD` set.
#[test]
fn lower_level_kernels_match_the_reference() {
    let tests = [
        "raster::tests::simd_level_follows_the_environment",
        "raster::tests::tiled_rasterizer_matches_per_pixel_reference",
        "raster::tests::backward_matches_finite_differences",
        "metrics::ssim::tests::matches_direct_reference",
        "metrics::ssim::tests::gradient_matches_finite_differences",
        "metrics::ssim::tests::gradient_matches_finite_differences_small_image",
    ];
    let lower = [("baseline", SimdLevel::Baseline), ("avx2", SimdLevel::Avx2)];
    for (name, level) in lower.into_iter().filter(|&(_, l)| l < simd_level()) {
        let out = std::process::Command::new(std::env::current_exe().unwrap())
            .args(tests)
            .args(["--exact", "--test-threads", "1"])
            .env("TADGS_SIMD", name)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{level:?} run failed:\n{stdout}");
        assert!(
            stdout.contains(&format!("{} passed", tests.len())),
            "expected {} tests to run at {level:?}:\n{stdout}",
            tests.len()
        );
    }
}
