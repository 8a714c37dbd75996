//! Property tests of the numerics: random cameras and Gaussians, degenerate ones included
//! (zero and huge scales, zero quaternions, points behind the camera or on the near plane,
//! huge opacity logits), never give NaN or infinity in the forward or backward pass, from
//! the per-Gaussian maths through the rasterizer to whole training steps.

mod tiny;

use std::sync::{Arc, OnceLock};

use glam::{Vec2, Vec3};
use proptest::prelude::*;
use tadgs::components::{Deformed, GaussianParams, Opacity, Param, Position, Rotation, Scale};
use tadgs::data::{Camera, Dataset};
use tadgs::model::project_lanes::{
    GaussianLanes, LANES, ProjectGradLanes, ViewTerms, project_backward_lanes,
};
use tadgs::model::{NEAR_PLANE, project, project_backward, rotation_at, sigmoid};
use tadgs::raster::Splat;
use tadgs::raster::{Rasterizer, RenderOutput, SplatGrad};
use tadgs::scene::SceneConfig;
use tadgs::systems::splat::{project_all, project_splat};
use tadgs::train::Trainer;

fn vec3(range: std::ops::Range<f32>) -> impl Strategy<Value = Vec3> {
    (range.clone(), range.clone(), range).prop_map(|(x, y, z)| Vec3::new(x, y, z))
}

/// A pinhole camera somewhere around the origin looking near it, of random size and field
/// of view.
fn camera() -> impl Strategy<Value = Camera> {
    (
        vec3(-6.0..6.0),
        vec3(-0.5..0.5),
        8u32..48,
        8u32..40,
        0.2f32..2.8,
    )
        .prop_filter("eye away from target", |(eye, target, ..)| {
            eye.distance(*target) > 0.5
        })
        .prop_map(|(eye, target, w, h, fov)| Camera::look_at(eye, target, Vec3::Y, w, h, fov))
}

/// Where a Gaussian sits relative to the camera.
#[derive(Clone, Copy, Debug)]
enum Place {
    /// Anywhere in a box around the scene.
    Free(Vec3),
    /// At this depth along the optical axis, offset sideways (0.0 = the camera centre,
    /// negative = behind the camera, NEAR_PLANE = on the near plane).
    OnAxis(f32, Vec2),
}

fn place() -> impl Strategy<Value = Place> {
    prop_oneof![
        3 => vec3(-3.0..3.0).prop_map(Place::Free),
        1 => (
            prop_oneof![
                Just(0.0),
                Just(NEAR_PLANE),
                Just(NEAR_PLANE * 1.0001),
                -5.0f32..0.0,
                0.0f32..0.05,
            ],
            (-0.1f32..0.1, -0.1f32..0.1).prop_map(|(x, y)| Vec2::new(x, y)),
        )
            .prop_map(|(depth, side)| Place::OnAxis(depth, side)),
    ]
}

fn world_point(place: Place, camera: &Camera) -> Vec3 {
    match place {
        Place::Free(p) => p,
        Place::OnAxis(depth, side) => {
            let to_world = camera.world_to_camera.inverse();
            to_world.transform_point3(Vec3::new(side.x * depth, side.y * depth, depth))
        }
    }
}

/// Log-scale per axis: ordinary, tiny, exactly zero scale (−∞), or huge up to overflow.
fn log_scale() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => -6.0f32..1.0,
        1 => -90.0f32..-6.0,
        1 => Just(f32::NEG_INFINITY),
        1 => 1.0f32..50.0,
    ]
}

/// Raw rotation polynomial coefficient: random, or exactly zero.
fn quaternion() -> impl Strategy<Value = [f32; 4]> {
    prop_oneof![
        4 => (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0)
            .prop_map(|(w, x, y, z)| [w, x, y, z]),
        1 => Just([0.0; 4]),
        1 => Just([1e-30, 0.0, 0.0, 0.0]),
    ]
}

/// Opacity logit: ordinary or huge in either direction.
fn opacity_logit() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => -8.0f32..8.0,
        1 => Just(1e4f32),
        1 => Just(-1e4f32),
        1 => Just(88.0f32),
    ]
}

/// One Gaussian as the splatting stage sees it (rotation normalised by `rotation_at` as in
/// the deform stage), before placement relative to a camera.
#[derive(Clone, Debug)]
struct Raw {
    place: Place,
    log_scale: [f32; 3],
    quat: [f32; 4],
    logit: f32,
    color: [f32; 3],
}

fn raw_gaussian() -> impl Strategy<Value = Raw> {
    (
        place(),
        [log_scale(), log_scale(), log_scale()],
        quaternion(),
        opacity_logit(),
        [0.0f32..1.5, 0.0f32..1.5, 0.0f32..1.5],
    )
        .prop_map(|(place, log_scale, quat, logit, color)| Raw {
            place,
            log_scale,
            quat,
            logit,
            color,
        })
}

fn deformed(raw: &Raw, camera: &Camera) -> Deformed {
    Deformed {
        mean: world_point(raw.place, camera).to_array(),
        rotation: rotation_at(raw.quat, [0.0; 4], 0.0),
        scale: raw.log_scale.map(f32::exp),
        opacity: sigmoid(raw.logit),
        color: raw.color,
    }
}

fn all_finite(values: &[f32]) -> bool {
    values.iter().all(|v| v.is_finite())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Projection: a Gaussian the projection keeps has a finite centre, conic, covariance
    /// and screen box and lies beyond the near plane; its backward pass gives finite
    /// gradients for any finite upstream gradient. Degenerate Gaussians are either culled
    /// or projected to finite values.
    #[test]
    fn projection_forward_and_backward_are_finite(
        camera in camera(),
        raw in raw_gaussian(),
        d_mean2d in (-1.0f32..1.0, -1.0f32..1.0),
        d_conic in [-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0],
    ) {
        let d = deformed(&raw, &camera);
        let (mean, scale) = (Vec3::from_array(d.mean), Vec3::from_array(d.scale));
        if let Some(p) = project(mean, d.rotation, scale, d.opacity, &camera) {
            prop_assert!(p.mean2d.is_finite() && p.extent.is_finite(), "{p:?}");
            prop_assert!(all_finite(&p.conic) && all_finite(&p.cov2d), "{p:?}");
            prop_assert!(p.depth >= NEAR_PLANE, "{p:?}");
            prop_assert!(p.extent.min_element() >= 0.0, "{p:?}");
            let g = project_backward(
                mean, d.rotation, scale, &camera, Vec2::new(d_mean2d.0, d_mean2d.1), d_conic,
            );
            prop_assert!(g.mean.is_finite() && g.scale.is_finite() && all_finite(&g.quat), "{g:?}");
        }
    }
}

/// A value that breaks the arithmetic, or none.
fn poison() -> impl Strategy<Value = Option<(usize, f32)>> {
    prop_oneof![
        6 => Just(None),
        1 => (0usize..14, prop_oneof![Just(f32::NAN), Just(f32::INFINITY), Just(-f32::INFINITY), Just(0.0), Just(-0.0)])
            .prop_map(Some),
    ]
}

/// Every float of a splat as bits, and its visibility.
fn splat_bits(s: &Splat) -> Vec<u32> {
    let floats = [
        s.mean2d.x, s.mean2d.y, s.conic[0], s.conic[1], s.conic[2], s.depth, s.opacity, s.color[0],
        s.color[1], s.color[2], s.extent.x, s.extent.y,
    ];
    floats
        .iter()
        .map(|v| v.to_bits())
        .chain([s.visible as u32])
        .collect()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// The splatting stage's projection of many Gaussians at once (eight per vector, in
    /// parallel chunks, a last group of fewer) gives every Gaussian the splat of the
    /// one-at-a-time projection bit for bit, culled ones included, also for Gaussians with a
    /// NaN, an infinity or a signed zero in any field.
    #[test]
    fn projection_of_many_equals_one_at_a_time(
        camera in camera(),
        raws in prop::collection::vec((raw_gaussian(), poison()), 1..40),
        near_plane in prop_oneof![Just(0.01f32), Just(0.0), 0.0f32..2.0],
        extra in 0usize..9,
    ) {
        let mut deformed_all: Vec<Deformed> = raws
            .iter()
            .map(|(raw, poison)| {
                let mut d = deformed(raw, &camera);
                if let Some((field, value)) = *poison {
                    bytemuck::cast_mut::<Deformed, [f32; 14]>(&mut d)[field] = value;
                }
                d
            })
            .collect();
        // More than one parallel chunk (4096 Gaussians), ending in a partial group.
        let target = 4096 + 8 * raws.len() + extra;
        let mut i = 0;
        while deformed_all.len() < target {
            deformed_all.push(deformed_all[i]);
            i += 1;
        }
        let mut splats = vec![Splat::default(); 3];
        project_all(&deformed_all, &camera, near_plane, &mut splats);
        prop_assert_eq!(splats.len(), deformed_all.len());
        for (k, (d, s)) in deformed_all.iter().zip(&splats).enumerate() {
            let one = project_splat(d, &camera, near_plane);
            prop_assert_eq!(splat_bits(s), splat_bits(&one), "Gaussian {}: {:?}", k, d);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// The projection backward of eight Gaussians at once gives every Gaussian the projection
    /// keeps the gradients of the one-at-a-time backward bit for bit (clamped Jacobians,
    /// degenerate scales and rotations included).
    #[test]
    fn projection_backward_of_eight_equals_one_at_a_time(
        camera in camera(),
        raws in prop::collection::vec(raw_gaussian(), LANES),
        d_mean2d in prop::collection::vec((-1.0f32..1.0, -1.0f32..1.0), LANES),
        d_conic in prop::collection::vec([-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0], LANES),
    ) {
        let deformed: Vec<Deformed> = raws.iter().map(|r| deformed(r, &camera)).collect();
        let mut lanes = GaussianLanes::default();
        let (mut d_mean2d_lanes, mut d_conic_lanes) = ([[0f32; LANES]; 2], [[0f32; LANES]; 3]);
        for (i, d) in deformed.iter().enumerate() {
            for k in 0..3 {
                lanes.mean[k][i] = d.mean[k];
                lanes.scale[k][i] = d.scale[k];
                d_conic_lanes[k][i] = d_conic[i][k];
            }
            for k in 0..4 {
                lanes.quat[k][i] = d.rotation[k];
            }
            d_mean2d_lanes[0][i] = d_mean2d[i].0;
            d_mean2d_lanes[1][i] = d_mean2d[i].1;
        }
        let mut chained = ProjectGradLanes::default();
        let terms = ViewTerms::new(&camera, NEAR_PLANE);
        project_backward_lanes(&lanes, &d_mean2d_lanes, &d_conic_lanes, &terms, &mut chained);
        for (i, d) in deformed.iter().enumerate() {
            let (mean, scale) = (Vec3::from_array(d.mean), Vec3::from_array(d.scale));
            if project(mean, d.rotation, scale, d.opacity, &camera).is_none() {
                continue;
            }
            let one = project_backward(
                mean, d.rotation, scale, &camera, Vec2::new(d_mean2d[i].0, d_mean2d[i].1), d_conic[i],
            );
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let lane = |v: &[[f32; LANES]]| v.iter().map(|l| l[i]).collect::<Vec<_>>();
            prop_assert_eq!(bits(&one.mean.to_array()), bits(&lane(&chained.mean)), "mean, Gaussian {}", i);
            prop_assert_eq!(bits(&one.quat), bits(&lane(&chained.quat)), "quat, Gaussian {}", i);
            prop_assert_eq!(bits(&one.scale.to_array()), bits(&lane(&chained.scale)), "scale, Gaussian {}", i);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Rasterizer: for any set of Gaussians (degenerate ones included) the rendered image
    /// is finite, coverage lies in [0, 1], and the backward pass gives finite gradients to
    /// every splat for any finite image gradient.
    #[test]
    fn rasterizer_forward_and_backward_are_finite(
        camera in camera(),
        raws in prop::collection::vec(raw_gaussian(), 1..40),
        background in [0.0f32..1.0, 0.0f32..1.0, 0.0f32..1.0],
        seed in any::<u32>(),
    ) {
        let splats: Vec<_> = raws.iter().map(|r| project_splat(&deformed(r, &camera), &camera, 0.01)).collect();
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut raster = Rasterizer::new();
        let mut out = RenderOutput::default();
        raster.forward(&splats, w, h, background, &mut out);
        prop_assert!(out.image.data.iter().all(|c| all_finite(c)));
        prop_assert!(out.alpha.iter().all(|a| (0.0..=1.0).contains(a)));
        // A deterministic pseudo-random image gradient in [−1, 1].
        let d_color: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let x = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed);
                [x, x >> 8, x >> 16].map(|v| (v & 0xff) as f32 / 127.5 - 1.0)
            })
            .collect();
        let mut grads: Vec<SplatGrad> = Vec::new();
        raster.backward(&splats, &d_color, w, &mut grads);
        prop_assert_eq!(grads.len(), splats.len());
        for g in &grads {
            prop_assert!(g.mean2d.is_finite() && all_finite(&g.conic) && all_finite(&g.color) && g.opacity.is_finite(), "{g:?}");
        }
    }
}

/// A 6-frame, 32×24 version of the demo scene and its rendered views, built once.
fn tiny_scene() -> &'static (SceneConfig, Arc<Dataset>) {
    static SCENE: OnceLock<(SceneConfig, Arc<Dataset>)> = OnceLock::new();
    SCENE.get_or_init(|| {
        let (mut config, dataset) = tiny::tiny_demo(32, 24, 60);
        // Densify and reset opacities inside the few steps each case runs.
        config.densify.from_iter = 1;
        config.densify.interval = 2;
        config.densify.opacity_reset_interval = 3;
        (config, dataset)
    })
}

fn params_finite(g: &GaussianParams) -> bool {
    all_finite(g.position.values())
        && all_finite(g.fourier.values())
        && all_finite(g.temporal.values())
        && all_finite(g.opacity.values())
        && all_finite(g.rotation.values())
        && all_finite(g.scale.values())
        && all_finite(g.color.values())
}

/// A degenerate edit of one Gaussian's parameters.
#[derive(Clone, Debug)]
enum Edit {
    Scale(f32),
    Opacity(f32),
    ZeroRotation,
    Position(Vec3),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        prop_oneof![Just(-80.0f32), Just(-30.0), Just(20.0), Just(40.0)].prop_map(Edit::Scale),
        opacity_logit().prop_map(Edit::Opacity),
        Just(Edit::ZeroRotation),
        // Far away, or near the ring of cameras (radius 4, height 1.5).
        prop_oneof![vec3(-1e4..1e4), vec3(-4.5..4.5)].prop_map(Edit::Position),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Training: with some Gaussians made degenerate, a few full training iterations
    /// (forward, loss, backward, Adam, densification, opacity reset) keep the loss and every
    /// parameter of every Gaussian finite.
    #[test]
    fn training_steps_stay_finite_with_degenerate_gaussians(
        edits in prop::collection::vec((0usize..360, edit()), 1..24),
        seed in 0u64..1000,
    ) {
        let (config, dataset) = tiny_scene();
        let mut config = config.clone();
        config.train.seed = seed;
        let mut trainer = Trainer::new(&config, dataset.clone());
        let mut query = trainer
            .world
            .query::<(&mut Position, &mut Scale, &mut Opacity, &mut Rotation)>();
        let mut gaussians: Vec<_> = query.iter_mut(&mut trainer.world).collect();
        let count = gaussians.len();
        for (index, edit) in &edits {
            let (position, scale, opacity, rotation) = &mut gaussians[index % count];
            match *edit {
                Edit::Scale(s) => scale.d0 = [s, 0.5 * s, s],
                Edit::Opacity(logit) => opacity.logit = logit,
                Edit::ZeroRotation => rotation.c0 = [0.0; 4],
                Edit::Position(p) => position.mean = p.to_array(),
            }
        }
        for _ in 0..4 {
            trainer.step();
            let loss = trainer.state().loss.total;
            prop_assert!(loss.is_finite(), "loss {loss} at iteration {}", trainer.state().iteration);
        }
        let model = trainer.model();
        for (i, g) in model.gaussians.iter().enumerate() {
            prop_assert!(params_finite(g), "Gaussian {i}: {g:?}");
        }
    }
}

/// Regression: splitting a Gaussian whose rotation is the zero quaternion used to give its
/// children NaN positions; with every rotation zero, training stays finite.
#[test]
fn splitting_zero_rotation_gaussians_stays_finite() {
    let (config, dataset) = tiny_scene();
    let mut config = config.clone();
    config.densify.grad_threshold = 1e-12; // every seen Gaussian densifies
    config.densify.percent_dense = 1e-9; // and splits rather than clones
    let mut trainer = Trainer::new(&config, dataset.clone());
    for mut rotation in trainer
        .world
        .query::<&mut Rotation>()
        .iter_mut(&mut trainer.world)
    {
        rotation.c0 = [0.0; 4];
    }
    let before = trainer.gaussian_count();
    for _ in 0..2 {
        trainer.step();
    }
    assert!(trainer.gaussian_count() > before, "some Gaussians split");
    assert!(trainer.model().gaussians.iter().all(params_finite));
}
