//! The whole differentiable pipeline — time warp, deformation, SH colour, EWA projection,
//! blending — against central finite differences, for every parameter of a few Gaussians seen
//! at a time away from their temporal centres. The loss is a fixed weighted sum of the image,
//! L = Σ w·I (accumulated in f64), set as the image gradient by a loss system of the test's
//! own; the photometric loss's own gradient is checked in `metrics::loss`.

use std::sync::Arc;

use bevy_ecs::prelude::*;
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tadgs::components::*;
use tadgs::data::{Camera, Dataset};
use tadgs::io::image::Image;
use tadgs::resources::{LossImage, SplatBuffers, TrainState, ViewSample};
use tadgs::scene::{DataSource, PhaseModel, SceneConfig};
use tadgs::systems::{TrainSet, add_backward_systems, add_render_systems, render_schedule};
use tadgs::train::insert_resources;

const W: u32 = 32;
const H: u32 = 24;

fn world(phase: PhaseModel, opacity_model: tadgs::scene::OpacityModel, smooth_warp: bool) -> World {
    let camera = Camera::look_at(Vec3::new(0.3, -0.2, -4.0), Vec3::ZERO, Vec3::Y, W, H, 1.2);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let target: Vec<[f32; 3]> = (0..(W * H) as usize)
        .map(|i| {
            let (x, y) = ((i % W as usize) as f32, (i / W as usize) as f32);
            [
                0.5 + 0.4 * (x * 0.3).sin(),
                0.5 + 0.4 * (y * 0.25).cos(),
                0.3 + 0.2 * ((x + y) * 0.2).sin(),
            ]
        })
        .collect();
    let frames = 11;
    let gt = Image {
        width: W as usize,
        height: H as usize,
        data: target,
    };
    let dataset = Dataset::single_camera(camera, frames, &gt);
    let mut config = SceneConfig::new(
        "gradients",
        DataSource::Synthetic(tadgs::data::synthetic::demo_scene()),
    );
    config.model.phase = phase;
    config.model.opacity = opacity_model;
    config.model.tow.window_frames = 4.0; // λ = 4/11: the view time lies outside some windows
    config.model.tow.smooth = smooth_warp;
    // Learnt temporal centres, so that their gradient is computed and checked too.
    config.train.lr.temporal_center = 1e-3;
    let mut world = World::new();
    insert_resources(&mut world, &config, Arc::new(dataset)).expect("CPU backend");
    world.resource_mut::<TrainState>().sh_degree = 3;
    *world.resource_mut::<ViewSample>() = ViewSample {
        camera,
        view: Some(7),
        frame: 7,
        time: 0.7,
        ..*world.resource::<ViewSample>()
    };

    // Wide, semi-transparent Gaussians near the optical axis: every pixel sees every Gaussian
    // above the 1/255 cut-off, so the loss is smooth in every parameter.
    for i in 0..4 {
        let mut small = |s: f32| rng.random_range(-s..s);
        let color = Color {
            dc: [0.4 + small(0.5), 0.4 + small(0.5), 0.4 + small(0.5)],
        };
        let mut color_rest = ColorRest::default();
        for k in 0..15 {
            color_rest.sh[k] = [small(0.1), small(0.1), small(0.1)];
        }
        let params = GaussianParams {
            position: Position {
                mean: [small(0.3), small(0.3), small(0.3)],
            },
            fourier: Fourier {
                cos: [[small(0.05), small(0.05), small(0.05)]; 4],
                sin: [[small(0.05), small(0.05), small(0.05)]; 4],
                phase: [small(1.0), small(1.0), small(1.0), small(1.0)],
            },
            temporal: Temporal {
                center: 0.2 + 0.2 * i as f32,
                scale: [0.2 + small(0.3), 0.1 + small(0.3)],
            },
            opacity: Opacity {
                logit: small(0.8) - 0.6,
            },
            rotation: Rotation {
                c0: [1.0, small(0.3), small(0.3), small(0.3)],
                c1: [small(0.2), small(0.2), small(0.2), small(0.2)],
            },
            scale: Scale {
                d0: [1.1 + small(0.2), 1.1 + small(0.2), 1.1 + small(0.2)],
                d1: [small(0.1), small(0.1), small(0.1)],
            },
            color,
            color_rest,
        };
        world.spawn((params.bundle(), params.optional_bundle()));
    }
    world
}

/// Measured jitter of the test loss between neighbouring parameter values (f32 rendering).
const LOSS_ROUNDING: f64 = 3e-5;

/// Per-pixel weights of the test loss.
#[derive(Resource)]
struct Weights(Vec<[f32; 3]>);

fn weighted_loss_gradient(weights: Res<Weights>, mut loss: ResMut<LossImage>) {
    loss.d_color.clone_from(&weights.0);
}

fn loss(world: &mut World, render: &mut Schedule) -> f64 {
    render.run(world);
    let image = &world.resource::<SplatBuffers>().render.image;
    let weights = &world.resource::<Weights>().0;
    image
        .data
        .iter()
        .zip(weights)
        .map(|(c, w)| (0..3).map(|i| c[i] as f64 * w[i] as f64).sum::<f64>())
        .sum()
}

/// Checks dL/dP for every value of every Gaussian's `P` against a five-point central difference with step
/// `h`: |analytic − fd| ≤ 1e-3·max(|analytic|, |fd|) + LOSS_ROUNDING / h. The floor is the
/// rounding noise of the quotient itself: the f32 render makes the loss (≈ 520) jitter by about
/// 3e-5 between nearby parameter values (measured), which the stencil divides by ≈ h.
fn check_group<P: Param + Copy>(
    world: &mut World,
    render: &mut Schedule,
    h: f32,
    skip: &[usize],
) -> usize {
    let entities: Vec<Entity> = world
        .query_filtered::<Entity, With<P>>()
        .iter(world)
        .collect();
    let mut checked = 0;
    for e in entities {
        let grad = world.get::<Grad<P>>(e).unwrap().0;
        let base = *world.get::<P>(e).unwrap();
        for i in (0..base.values().len()).filter(|i| !skip.contains(i)) {
            let mut eval = |delta: f32| {
                let mut p = base;
                p.values_mut()[i] += delta;
                *world.get_mut::<P>(e).unwrap() = p;
                loss(world, render)
            };
            // Five-point stencil: truncation error O(h⁴), so steps can be large enough to rise
            // above f32 rounding.
            let fd =
                (8.0 * (eval(h) - eval(-h)) - (eval(2.0 * h) - eval(-2.0 * h))) / (12.0 * h as f64);
            *world.get_mut::<P>(e).unwrap() = base;
            let analytic = grad.values()[i] as f64;
            let tol = 1e-3 * analytic.abs().max(fd.abs()) + LOSS_ROUNDING / h as f64;
            assert!(
                (analytic - fd).abs() <= tol,
                "{} value {i}: analytic {analytic:e}, finite difference {fd:e}",
                P::NAME
            );
            checked += 1;
        }
    }
    checked
}

// Steps: pixel positions are f32 (≈ 2e-6 px apart near the image centre), so a step must move
// the splat by much more than that; these are the smallest that keep the rounding noise of the
// difference quotient under the tolerance.
const H_POSITION: f32 = 3e-2;
const H_FOURIER: f32 = 3e-2;
const H_TEMPORAL: f32 = 1e-2;
const H_OPACITY: f32 = 1e-2;
const H_ROTATION: f32 = 3e-2;
const H_SCALE: f32 = 1e-2;
const H_COLOR: f32 = 1e-2;

fn check_all(phase: PhaseModel, opacity: tadgs::scene::OpacityModel, smooth_warp: bool) {
    let mut world = world(phase, opacity, smooth_warp);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    world.insert_resource(Weights(
        (0..W * H)
            .map(|_| [rng.random(), rng.random(), rng.random()])
            .collect(),
    ));
    let mut gradients = Schedule::default();
    add_render_systems(&mut gradients);
    gradients.add_systems(weighted_loss_gradient.in_set(TrainSet::Loss));
    add_backward_systems(&mut gradients);
    gradients.run(&mut world);
    let mut render = render_schedule();
    let mut checked = 0;
    checked += check_group::<Position>(&mut world, &mut render, H_POSITION, &[]);
    checked += check_group::<Fourier>(&mut world, &mut render, H_FOURIER, &[]);
    checked += check_group::<Temporal>(&mut world, &mut render, H_TEMPORAL, &[]);
    checked += check_group::<Opacity>(&mut world, &mut render, H_OPACITY, &[]);
    checked += check_group::<Rotation>(&mut world, &mut render, H_ROTATION, &[]);
    checked += check_group::<Scale>(&mut world, &mut render, H_SCALE, &[]);
    checked += check_group::<Color>(&mut world, &mut render, H_COLOR, &[]);
    checked += check_group::<ColorRest>(&mut world, &mut render, H_COLOR, &[]);
    // Every value, the temporal centre included.
    assert_eq!(checked, 4 * (3 + 28 + 3 + 1 + 8 + 6 + 48));
}

#[test]
fn every_parameter_gradient_matches_finite_differences_paper_model() {
    check_all(
        PhaseModel::PerGaussian,
        tadgs::scene::OpacityModel::Rbf,
        false,
    );
}

/// The same with TOW's rounded corners (`model.tow.smooth`), whose slope W' enters the
/// temporal centres' gradient.
#[test]
fn every_parameter_gradient_matches_finite_differences_smooth_warp() {
    check_all(
        PhaseModel::PerGaussian,
        tadgs::scene::OpacityModel::Rbf,
        true,
    );
}

#[test]
fn every_parameter_gradient_matches_finite_differences_implementation_model() {
    check_all(
        PhaseModel::PerFrequency,
        tadgs::scene::OpacityModel::Asymmetric,
        false,
    );
}
