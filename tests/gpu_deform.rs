//! The GPU deformation, projection and parameter-gradient kernels ([`GpuDeformer`]) equal the
//! CPU systems they mirror (`systems::deform::deform`, `systems::splat::splat`'s projection,
//! `systems::backward::{backward_splats, backward_parameters}`), run in a `World` on the same
//! random populations: every temporal opacity model, SH degrees 0 and 3, scale motion and
//! shared phase on and off, random cameras with Gaussians behind the camera, straddling the
//! near plane, too transparent or off screen, and population sizes that grow and shrink the
//! GPU buffers (0 and 1 included).
//!
//! The test fails on real slips: checked by hand with a halved term of the projection's
//! backward, a typo in an SH constant, the near plane fixed at 0.01, the scale-motion switch
//! ignored and the shared phase gradient spread over the frequencies, each caught.

#[path = "common/gpu.rs"]
#[allow(dead_code)]
mod gpu;

use std::time::Instant;

use bevy_ecs::prelude::*;
use bevy_ecs::system::RunSystemOnce;
use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tadgs::components::*;
use tadgs::data::Camera;
use tadgs::gpu::{DeformSettings, GpuDeformer, ParamGradients, ParamSlices};
use tadgs::model::{TemporalOpacity, sh_to_rgb};
use tadgs::raster::Splat;
use tadgs::resources::{
    DeformEveryGaussian, LossImage, Settings, SplatBuffers, TrainState, ViewSample,
};
use tadgs::scene::{DataSource, PhaseModel, SceneConfig};
use tadgs::systems::backward::{backward_parameters, backward_splats};
use tadgs::systems::deform::deform;
use tadgs::systems::splat::{deformed_by_slot, project_all, splat};
use tadgs::train::insert_render_resources;

// Tolerance: each GPU value v of a CPU value c is held to
//   |v − c| ≤ REL·|c| + REL·GROUP_FLOOR·(group magnitude) + NOISE_FACTOR·(group noise)
//             + f32::MIN_POSITIVE
// where a group is the values of one quantity of one Gaussian (its three mean coordinates, its
// 28 Fourier gradients, …), its magnitude the largest |c| in it, and its noise how far the
// CPU's own result moves when its inputs move by a few ulps (measured per Gaussian in
// `run_cpu`). The kernels evaluate the same expressions in the same order, but the GPU may fuse
// multiply-adds and its exp/log/sin/cos differ from libm by a few ulps, so they agree to f32
// rounding of the *inputs* of each value, not of the value: a gradient component summed from
// much larger terms, or anything downstream of an ill-conditioned step, differs by more than
// 1e-4 of itself. Measured cases: the 2D conic of a long thin footprint (det cov2d cancels),
// the camera depth and view direction of a Gaussian at the near plane (μ(t) − eye cancels),
// the extent of a splat at the 1/255 opacity cut-off (ln(255·σ) ≈ 0); there the CPU moves by
// up to ~3e-4 of the group under 1e-7 relative input nudges, and the GPU differs by a few
// times that. Elsewhere the noise term is far below REL·|c|. The last term covers results that
// are subnormal on the CPU and flushed to zero on the GPU (far tails of exp).

/// Relative tolerance of every comparison.
const REL: f32 = 1e-4;
/// Floor as a fraction of the group's magnitude, for values that cancel to nearly 0.
const GROUP_FLOOR: f32 = 1e-3;
/// Relative size of the input nudges that measure a Gaussian's conditioning (about 20 ulps:
/// the GPU's deformed values differ from the CPU's by up to ~3e-6, e.g. through exp).
const PERTURBATION: f32 = 2e-6;
/// Nudged reruns per population.
const NOISE_TRIALS: usize = 4;
/// The floor's multiple of the measured noise: the GPU also rounds every intermediate, not
/// only the inputs (worst seen over 16 seeds: about 0.55 of the resulting tolerance).
const NOISE_FACTOR: f32 = 8.0;
/// The rounding noise of a colour: 0.5 plus SH terms of order 1, so about 1e-7 absolute
/// however small the sum (a channel just above the clamp at 0).
const COLOR_NOISE: f32 = 2.5e-7;

/// One configuration of the model and view.
#[derive(Clone, Copy, Debug)]
struct Case {
    gaussians: usize,
    opacity: TemporalOpacity,
    sh_degree: u32,
    scale_motion: bool,
    shared_phase: bool,
    /// `model.motion_period`.
    motion_period: f32,
    near_plane: f32,
    /// Upload through `upload_components` (else `upload_params`).
    components: bool,
}

fn cases() -> Vec<Case> {
    // w_min ≈ 0.39 (T = 50): many widths clamp at 1.1; w_min ≈ 0.064 (T = 300): few do.
    let (rbf, wide, narrow) = (
        TemporalOpacity::Rbf,
        TemporalOpacity::asymmetric(50),
        TemporalOpacity::asymmetric(300),
    );
    let case = |gaussians, opacity, sh_degree, scale_motion, shared_phase, near_plane| Case {
        gaussians,
        opacity,
        sh_degree,
        scale_motion,
        shared_phase,
        motion_period: 1.0,
        near_plane,
        components: gaussians % 2 == 0,
    };
    vec![
        case(1500, rbf, 3, true, true, 0.01),
        case(701, rbf, 0, false, false, 0.3),
        case(3000, wide, 3, false, true, 0.01),
        case(1, wide, 3, true, true, 0.01),
        case(1200, wide, 0, true, false, 0.3),
        case(0, narrow, 3, true, true, 0.01),
        case(2001, narrow, 3, true, false, 0.01),
        case(900, narrow, 0, false, true, 0.3),
        case(1600, rbf, 3, false, false, 0.3),
        Case {
            motion_period: 2.0,
            ..case(1100, rbf, 3, true, true, 0.01)
        },
        Case {
            motion_period: 0.5,
            ..case(800, narrow, 1, true, false, 0.01)
        },
    ]
}

/// A camera orbiting the origin at 2.5–4 units (the population spans ±2, so some Gaussians
/// are behind it), with unequal focal lengths and an off-centre principal point.
fn random_camera(rng: &mut ChaCha8Rng) -> Camera {
    let azimuth = rng.random_range(0.0..std::f32::consts::TAU);
    let elevation = rng.random_range(-0.8f32..0.8);
    let distance = rng.random_range(2.5..4.0);
    let eye = distance
        * Vec3::new(
            elevation.cos() * azimuth.cos(),
            elevation.sin(),
            elevation.cos() * azimuth.sin(),
        );
    let target = Vec3::new(
        rng.random_range(-0.3..0.3),
        rng.random_range(-0.3..0.3),
        rng.random_range(-0.3..0.3),
    );
    let width = rng.random_range(40..97);
    let height = rng.random_range(30..73);
    let mut camera = Camera::look_at(
        eye,
        target,
        Vec3::Y,
        width,
        height,
        rng.random_range(0.6..1.6),
    );
    camera.fy = camera.fx * rng.random_range(0.9..1.1);
    camera.cx += rng.random_range(-3.0..3.0);
    camera.cy += rng.random_range(-3.0..3.0);
    camera
}

fn uniform<const N: usize>(rng: &mut ChaCha8Rng, lo: f32, hi: f32) -> [f32; N] {
    std::array::from_fn(|_| rng.random_range(lo..hi))
}

/// A random Gaussian and its warped time. Kinds: most in the ±2 box around the origin; some
/// placed without motion just in front of or behind the near plane; some nearly transparent;
/// a few with a zero rotation polynomial (the identity branch) or at Δt' = 0.
fn random_gaussian(
    rng: &mut ChaCha8Rng,
    case: &Case,
    camera: &Camera,
) -> (GaussianParams, WarpedTime) {
    let color = Color {
        dc: uniform(rng, -1.5, 2.0),
    };
    let mut color_rest = ColorRest::default();
    for k in 0..15 {
        color_rest.sh[k] = uniform(rng, -0.5, 0.5);
    }
    let temporal_scale = match case.opacity {
        TemporalOpacity::Rbf => [rng.random_range(-3.0..4.0), rng.random_range(-1.0..1.0)],
        TemporalOpacity::Asymmetric { .. } => uniform(rng, -2.0, 3.0),
    };
    let mut params = GaussianParams {
        position: Position {
            mean: uniform(rng, -2.0, 2.0),
        },
        fourier: Fourier {
            cos: std::array::from_fn(|_| uniform(rng, -0.15, 0.15)),
            sin: std::array::from_fn(|_| uniform(rng, -0.15, 0.15)),
            phase: uniform(rng, -3.2, 3.2),
        },
        temporal: Temporal {
            center: rng.random_range(0.0..1.0),
            scale: temporal_scale,
        },
        opacity: Opacity {
            logit: rng.random_range(-4.0..2.0),
        },
        rotation: Rotation {
            c0: uniform(rng, -1.0, 1.0),
            c1: uniform(rng, -0.5, 0.5),
        },
        scale: Scale {
            d0: uniform(rng, -4.0, -0.8),
            d1: uniform(rng, -1.0, 1.0),
        },
        color,
        color_rest,
    };
    let mut dtw = rng.random_range(-1.0..1.0);
    match rng.random_range(0..20) {
        0 | 1 => {
            // At the near plane: camera depth within ±0.03 of it, no motion.
            let depth = case.near_plane.max(0.01) + rng.random_range(-0.03..0.03);
            let camera_point = Vec3::new(
                rng.random_range(-0.02..0.02),
                rng.random_range(-0.02..0.02),
                depth,
            );
            let world = camera
                .world_to_camera
                .inverse()
                .transform_point3(camera_point);
            params.position.mean = world.to_array();
            params.fourier = Fourier::default();
            // Faint and small, so that it does not hide the rest of the image.
            params.opacity.logit = rng.random_range(-5.0..-4.0);
            params.scale.d0 = uniform(rng, -7.0, -5.0);
        }
        2 => params.opacity.logit = rng.random_range(-9.0..-5.0),
        3 => {
            params.rotation = Rotation::default();
            dtw = 0.0;
        }
        _ => {}
    }
    let warped = WarpedTime { dt: dtw, dtw };
    (params, warped)
}

/// What the CPU systems produce, in slot order.
#[derive(Default)]
struct CpuResult {
    params: Vec<GaussianParams>,
    warped: Vec<WarpedTime>,
    /// The deformed Gaussians in slot order.
    deformed: Vec<Deformed>,
    buffers: SplatBuffers,
    grads: ParamGradients,
    /// Per Gaussian and gradient group: how far the CPU's own gradients move when its inputs
    /// move by a few ulps (see [`run_cpu`]).
    noise: Vec<[f32; 7]>,
    /// The same for the projected fields of [`PROJECTED_GROUPS`].
    splat_noise: Vec<[f32; 4]>,
    /// The same for the colour (at least [`COLOR_NOISE`]).
    color_noise: Vec<f32>,
}

/// The [`splat_fields`] computed by the projection (mean2d, conic, depth, extent); opacity and
/// colour are copied from the deformed Gaussian.
const PROJECTED_GROUPS: [std::ops::Range<usize>; 4] = [0..2, 2..5, 5..6, 10..12];

/// Spawns `gaussians` and runs the CPU systems from deformation to the parameter gradients,
/// with a random image gradient standing in for the loss.
fn run_cpu(
    case: &Case,
    camera: Camera,
    gaussians: &[(GaussianParams, WarpedTime)],
    rng: &mut ChaCha8Rng,
) -> (World, CpuResult) {
    let scene = SceneConfig::new(
        "gpu_deform",
        DataSource::Synthetic(tadgs::data::synthetic::demo_scene()),
    );
    let mut world = World::new();
    insert_render_resources(&mut world, &scene, 50, 3.0, camera).expect("CPU backend");
    {
        let mut settings = world.resource_mut::<Settings>();
        settings.opacity = case.opacity;
        settings.model.phase = if case.shared_phase {
            PhaseModel::PerGaussian
        } else {
            PhaseModel::PerFrequency
        };
        settings.model.motion_period = case.motion_period;
        settings.model.scale_motion = case.scale_motion;
        settings.train.near_plane = case.near_plane;
    }
    world.resource_mut::<TrainState>().sh_degree = case.sh_degree;
    world.resource_mut::<ViewSample>().camera = camera;
    // The GPU kernel evaluates every Gaussian, faded ones included: so does the CPU stage here.
    world.insert_resource(DeformEveryGaussian);
    let pixels = (camera.width * camera.height) as usize;
    world.insert_resource(LossImage {
        d_color: (0..pixels).map(|_| uniform(rng, -1.0, 1.0)).collect(),
        ..Default::default()
    });
    for (params, warped) in gaussians {
        let e = world
            .spawn((params.bundle(), params.optional_bundle()))
            .id();
        *world.get_mut::<WarpedTime>(e).unwrap() = *warped;
    }

    world.run_system_once(deform).unwrap();
    world
        .run_system_once::<_, bevy_ecs::error::Result, _>(splat)
        .unwrap()
        .unwrap();
    world
        .run_system_once::<_, bevy_ecs::error::Result, _>(backward_splats)
        .unwrap()
        .unwrap();
    world.run_system_once(backward_parameters).unwrap();

    let mut out = CpuResult::default();
    out.grads = collect_grads(&mut world, &mut out.params, &mut out.warped);

    // The conditioning of each Gaussian's gradients: rerun the backward systems with the
    // deformed Gaussians they read (projection and SH direction) nudged by up to PERTURBATION
    // relative, and record how far each gradient group moves.
    let reference = deformed_by_slot(&mut world);
    out.noise = vec![[0.0; 7]; reference.len()];
    for _ in 0..NOISE_TRIALS {
        let nudged = nudge_deformed(&reference, rng, false);
        // Both backward systems read the Deformed components.
        set_deformed(&mut world, &nudged);
        world
            .run_system_once::<_, bevy_ecs::error::Result, _>(backward_splats)
            .unwrap()
            .unwrap();
        world.run_system_once(backward_parameters).unwrap();
        let nudged = collect_grads(&mut world, &mut Vec::new(), &mut Vec::new());
        for (i, noise) in out.noise.iter_mut().enumerate() {
            let groups = grad_groups(&out.grads, i);
            let moved = grad_groups(&nudged, i);
            for (n, (a, b)) in noise.iter_mut().zip(groups.iter().zip(&moved)) {
                let deviation = a
                    .iter()
                    .zip(*b)
                    .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
                *n = n.max(deviation);
            }
        }
        set_deformed(&mut world, &reference);
    }
    // The same for the projection: the splats of nudged deformed Gaussians, where both are
    // drawn (a splat at a culling threshold may flip).
    let reference_splats = world.resource::<SplatBuffers>().splats.clone();
    out.splat_noise = vec![[0.0; 4]; reference.len()];
    out.color_noise = vec![COLOR_NOISE; reference.len()];
    let eye = camera.center();
    let mut nudged_splats = Vec::new();
    for _ in 0..NOISE_TRIALS {
        // The extent's ln(255·σ) is near 0 for σ near the 1/255 cut-off.
        let nudged = nudge_deformed(&reference, rng, true);
        project_all(&nudged, &camera, case.near_plane, &mut nudged_splats);
        // The colour's view direction μ(t) − eye is short for Gaussians near the camera.
        for ((noise, d), (r, p)) in out
            .color_noise
            .iter_mut()
            .zip(&nudged)
            .zip(reference.iter().zip(&out.params))
        {
            let color = sh_to_rgb(case.sh_degree, &p.sh(), Vec3::from(d.mean) - eye);
            for (a, b) in color.iter().zip(&r.color) {
                *noise = noise.max((a - b).abs());
            }
        }
        for (noise, (a, b)) in out
            .splat_noise
            .iter_mut()
            .zip(reference_splats.iter().zip(&nudged_splats))
        {
            if a.visible && b.visible {
                let (a, b) = (splat_fields(a), splat_fields(b));
                for (n, range) in noise.iter_mut().zip(PROJECTED_GROUPS) {
                    let deviation = a[range.clone()]
                        .iter()
                        .zip(&b[range])
                        .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
                    *n = n.max(deviation);
                }
            }
        }
    }
    // Back to the unperturbed state (the rasterizer's is unchanged).
    world
        .run_system_once::<_, bevy_ecs::error::Result, _>(backward_splats)
        .unwrap()
        .unwrap();
    out.buffers = world.remove_resource::<SplatBuffers>().unwrap();
    out.deformed = reference;
    (world, out)
}

/// `reference` with every mean, rotation and scale value (and opacity, with `opacity`) scaled by
/// a random factor within 1 ± PERTURBATION.
fn nudge_deformed(reference: &[Deformed], rng: &mut impl Rng, opacity: bool) -> Vec<Deformed> {
    let mut nudged = reference.to_vec();
    let mut nudge = |v: &mut f32| *v *= 1.0 + rng.random_range(-PERTURBATION..PERTURBATION);
    for d in &mut nudged {
        d.mean.iter_mut().for_each(&mut nudge);
        d.rotation.iter_mut().for_each(&mut nudge);
        d.scale.iter_mut().for_each(&mut nudge);
        if opacity {
            nudge(&mut d.opacity);
        }
    }
    nudged
}

/// Sets each Gaussian's Deformed component to `deformed[slot]`.
fn set_deformed(world: &mut World, deformed: &[Deformed]) {
    for (slot, mut d) in world.query::<(&SplatSlot, &mut Deformed)>().iter_mut(world) {
        *d = deformed[slot.0 as usize];
    }
}

/// The parameter gradients in slot order, with the parameters and warped times they belong to.
fn collect_grads(
    world: &mut World,
    params: &mut Vec<GaussianParams>,
    warped: &mut Vec<WarpedTime>,
) -> ParamGradients {
    let mut rows: Vec<_> = world
        .query::<(
            &SplatSlot,
            ParamRefs,
            &WarpedTime,
            (
                &Grad<Position>,
                &Grad<Fourier>,
                &Grad<Temporal>,
                &Grad<Opacity>,
                &Grad<Rotation>,
                &Grad<Scale>,
                &Grad<Color>,
                &Grad<ColorRest>,
            ),
        )>()
        .iter(world)
        .map(|(slot, refs, w, g)| {
            (
                slot.0,
                GaussianParams::from_refs(refs),
                *w,
                (
                    *g.0,
                    *g.1,
                    *g.2,
                    *g.3,
                    *g.4,
                    *g.5,
                    sh_coefficients(&g.6.0, Some(&g.7.0)),
                ),
            )
        })
        .collect();
    rows.sort_by_key(|r| r.0);
    let mut grads = ParamGradients::default();
    for (_, p, w, g) in rows {
        params.push(p);
        warped.push(w);
        grads.position.push(g.0);
        grads.fourier.push(g.1);
        grads.temporal.push(g.2);
        grads.opacity.push(g.3);
        grads.rotation.push(g.4);
        grads.scale.push(g.5);
        grads.color.push(g.6);
    }
    grads
}

/// Names of the parameter gradient groups, in [`grad_groups`] order.
const GRAD_GROUPS: [&str; 7] = [
    "grad position",
    "grad fourier",
    "grad temporal",
    "grad opacity",
    "grad rotation",
    "grad scale",
    "grad color",
];

/// Gaussian `i`'s gradient of each parameter component, as flat values.
fn grad_groups(g: &ParamGradients, i: usize) -> [&[f32]; 7] {
    [
        g.position[i].0.values(),
        g.fourier[i].0.values(),
        g.temporal[i].0.values(),
        g.opacity[i].0.values(),
        g.rotation[i].0.values(),
        g.scale[i].0.values(),
        g.color[i].as_flattened(),
    ]
}

/// The worst error seen per quantity, for the report: as a fraction of its tolerance, and
/// relative to the CPU value among values at least 1% of their group's magnitude.
#[derive(Default)]
struct Errors {
    worst: Vec<(&'static str, f32, f32)>,
    /// The first failures and how many there were.
    failures: Vec<String>,
    failed: usize,
}

impl Errors {
    /// Checks `gpu` against `cpu`, a group of values of one quantity of Gaussian `index`
    /// whose measured conditioning noise (0 where not measured) is `noise`.
    fn check(
        &mut self,
        context: &str,
        name: &'static str,
        index: usize,
        gpu: &[f32],
        cpu: &[f32],
        noise: f32,
    ) {
        assert_eq!(gpu.len(), cpu.len());
        let magnitude = cpu.iter().fold(0f32, |m, v| m.max(v.abs()));
        let floor = REL * GROUP_FLOOR * magnitude + NOISE_FACTOR * noise + f32::MIN_POSITIVE;
        let entry = match self.worst.iter().position(|w| w.0 == name) {
            Some(i) => i,
            None => {
                self.worst.push((name, 0.0, 0.0));
                self.worst.len() - 1
            }
        };
        for (k, (&g, &c)) in gpu.iter().zip(cpu).enumerate() {
            let err = (g - c).abs();
            let bound = REL * c.abs() + floor;
            if err.is_nan() || err > bound {
                self.failed += 1;
                if self.failures.len() < 8 {
                    self.failures.push(format!(
                        "{context}: Gaussian {index} {name}[{k}]: GPU {g} vs CPU {c} (error \
                         {err:e}, bound {bound:e}; group {gpu:?} vs {cpu:?})"
                    ));
                }
            }
            let w = &mut self.worst[entry];
            w.1 = w.1.max(if bound > 0.0 { err / bound } else { 0.0 });
            if c.abs() >= 1e-2 * magnitude && c != 0.0 {
                w.2 = w.2.max(err / c.abs());
            }
        }
    }
}

fn splat_fields(s: &Splat) -> [f32; 12] {
    [
        s.mean2d.x, s.mean2d.y, s.conic[0], s.conic[1], s.conic[2], s.depth, s.opacity, s.color[0],
        s.color[1], s.color[2], s.extent.x, s.extent.y,
    ]
}

#[test]
fn gpu_deform_project_and_gradients_equal_cpu_systems() {
    let Some(mut gpu) = gpu::open_or_skip(GpuDeformer::new) else {
        return;
    };
    eprintln!("adapter: {}", gpu.describe());
    let start = Instant::now();
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    let mut errors = Errors::default();
    let (mut deformed, mut splats, mut ndc) = (Vec::new(), Vec::new(), Vec::new());
    let mut grads = ParamGradients::default();
    let (mut visible_total, mut drawn_total, mut culled_near) = (0, 0, 0);
    for case in cases() {
        let camera = random_camera(&mut rng);
        let population: Vec<_> = (0..case.gaussians)
            .map(|_| random_gaussian(&mut rng, &case, &camera))
            .collect();
        let (world, cpu) = run_cpu(&case, camera, &population, &mut rng);
        let context = format!("{case:?}");
        let n = cpu.params.len();

        if case.components {
            let all = &cpu.params;
            let position: Vec<Position> = all.iter().map(|p| p.position).collect();
            let fourier: Vec<Fourier> = all.iter().map(|p| p.fourier).collect();
            let temporal: Vec<Temporal> = all.iter().map(|p| p.temporal).collect();
            let opacity: Vec<Opacity> = all.iter().map(|p| p.opacity).collect();
            let rotation: Vec<Rotation> = all.iter().map(|p| p.rotation).collect();
            let scale: Vec<Scale> = all.iter().map(|p| p.scale).collect();
            let color: Vec<ShCoefficients> = all.iter().map(|p| p.sh()).collect();
            let slices = ParamSlices {
                position: &position,
                fourier: &fourier,
                temporal: &temporal,
                opacity: &opacity,
                rotation: &rotation,
                scale: &scale,
                color: &color,
            };
            gpu.upload_components(slices, &cpu.warped).unwrap();
        } else {
            gpu.upload_params(&cpu.params, &cpu.warped).unwrap();
        }
        let settings =
            DeformSettings::new(world.resource::<Settings>(), world.resource::<TrainState>());
        gpu.forward(&camera, &settings);
        gpu.read_deformed(&mut deformed).unwrap();
        gpu.read_splats(&mut splats).unwrap();
        gpu.backward(&cpu.buffers.splat_grads);
        gpu.read_grads(&mut grads).unwrap();
        gpu.read_ndc_grad_norm(&mut ndc).unwrap();
        assert_eq!(gpu.len(), n);
        assert_eq!((deformed.len(), splats.len(), ndc.len()), (n, n, n));

        let b = &cpu.buffers;
        for i in 0..n {
            let (g, c) = (&deformed[i], &cpu.deformed[i]);
            errors.check(&context, "deformed mean", i, &g.mean, &c.mean, 0.0);
            errors.check(
                &context,
                "deformed rotation",
                i,
                &g.rotation,
                &c.rotation,
                0.0,
            );
            errors.check(&context, "deformed scale", i, &g.scale, &c.scale, 0.0);
            errors.check(
                &context,
                "deformed opacity",
                i,
                &[g.opacity],
                &[c.opacity],
                0.0,
            );
            errors.check(
                &context,
                "deformed color",
                i,
                &g.color,
                &c.color,
                cpu.color_noise[i],
            );

            let (g, c) = (&splats[i], &b.splats[i]);
            assert_eq!(
                g.visible, c.visible,
                "{context}: Gaussian {i} visibility: GPU {g:?} vs CPU {c:?} (deformed {:?})",
                cpu.deformed[i]
            );
            if c.visible {
                visible_total += 1;
                let (gf, cf) = (splat_fields(g), splat_fields(c));
                let noise = cpu.splat_noise[i];
                for (g, name) in ["splat mean2d", "splat conic", "splat depth", "splat extent"]
                    .into_iter()
                    .enumerate()
                {
                    let range = PROJECTED_GROUPS[g].clone();
                    errors.check(&context, name, i, &gf[range.clone()], &cf[range], noise[g]);
                }
                errors.check(&context, "splat opacity", i, &gf[6..7], &cf[6..7], 0.0);
                errors.check(
                    &context,
                    "splat color",
                    i,
                    &gf[7..10],
                    &cf[7..10],
                    cpu.color_noise[i],
                );
                if b.splat_grads[i].mean2d != glam::Vec2::ZERO {
                    drawn_total += 1;
                }
            } else {
                // Culled: exactly the CPU's Splat::default().
                assert_eq!(*g, Splat::default(), "{context}: Gaussian {i}");
                let depth = camera
                    .world_to_camera
                    .transform_point3(Vec3::from(cpu.deformed[i].mean))
                    .z;
                if depth < case.near_plane.max(0.01) && depth > -0.05 {
                    culled_near += 1;
                }
            }
            errors.check(
                &context,
                "ndc grad norm",
                i,
                &[ndc[i]],
                &[b.ndc_grad_norm[i]],
                0.0,
            );

            let (gpu_groups, cpu_groups) = (grad_groups(&grads, i), grad_groups(&cpu.grads, i));
            for (g, name) in GRAD_GROUPS.iter().enumerate() {
                let noise = cpu.noise[i][g];
                errors.check(&context, name, i, gpu_groups[g], cpu_groups[g], noise);
            }
        }
    }
    // The populations exercise both sides of every cut: drawn splats with gradients, and
    // Gaussians culled at the near plane.
    let total: usize = cases().iter().map(|c| c.gaussians).sum();
    eprintln!(
        "{total} Gaussians: {visible_total} visible, {drawn_total} with a 2D mean gradient, {culled_near} culled at the near plane"
    );
    for (name, ratio, rel) in &errors.worst {
        eprintln!(
            "{name:>18}: worst error {ratio:.2e} of the tolerance; {rel:.1e} relative (values ≥ 1% of their group)"
        );
    }
    assert!(visible_total > total / 5 && drawn_total > total / 10 && culled_near > 20);
    assert!(
        errors.failed == 0,
        "{} values differ; the first:\n{}",
        errors.failed,
        errors.failures.join("\n")
    );
    eprintln!("parity test took {:.1} s", start.elapsed().as_secs_f32());
}
