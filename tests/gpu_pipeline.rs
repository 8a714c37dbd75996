//! The GPU-resident training pipeline (`GpuTraining`, `systems::resident`) against the CPU
//! schedule: one iteration on a small random scene gives the same render, Adam state and
//! densification statistics (also the baseline's, which counts faded Gaussians); several
//! iterations with densification (read back, CPU densification, upload) track the CPU run; and the non-finite gradient check trips.
//!
//! Tolerances. The render is held to 1e-4 absolute (the kernels blend in the CPU's order;
//! the deformation and projection agree to f32 rounding, see tests/gpu_deform.rs). Gradients
//! (the `Grad<P>` components) are held to 1e-4 relative plus 1e-4 of the largest value of
//! their parameter group (the blending sums of the backward run in another order; the bound of
//! tests/gpu_schedule.rs), and Adam's moments after one step, m = (1 − β1)·g and
//! √(v / (1 − β2)) = |g|, to the same bound plus 1.5 spacings of bfloat16 (the CPU stores its
//! moments in bfloat16, the GPU keeps them in f32 and rounds them to nearest when read back). The parameters themselves move by
//! lr·m̂/(√v̂ + ε) = ±lr on a first step whatever |g|, so a value whose gradient is within the
//! gradient tolerance of zero may legitimately step the other way: every parameter must equal
//! the CPU's to 1e-6·(1 + |p|) unless its CPU gradient is that small (the count of such sign
//! flips is printed; it is a few per thousand at most). Statistics: the visible-view count
//! exactly, the weights and lifespans to 1e-4 relative, the weighted gradient to the gradient
//! bound and the largest screen radius to 1e-3 relative (it comes from ln and sqrt of the
//! opacity and covariance).
//!
//! After a sync the `Grad<P>` components equal the CPU's to the gradient bound above and
//! `Deformed` to 1e-5 relative (plus 1e-5 of the largest value).
//!
//! Checked by hand to fail: Adam's section offset ignored, the statistics reading the Opacity
//! section instead of Temporal, the gradient check taking the maximum index (so never tripping).

#[path = "common/demo.rs"]
mod demo;
#[path = "common/gpu.rs"]
mod gpu;
#[path = "common/rows.rs"]
mod rows;

use std::sync::Arc;
use std::time::Instant;

use bevy_ecs::prelude::*;
use rows::in_entity_order;
use tadgs::components::*;
use tadgs::data::Dataset;
use tadgs::gpu::{DeformSettings, GpuContext, GpuTraining, ResidentState};
use tadgs::resources::{Settings, SplatBuffers, TrainState, ViewOrder, ViewSample};
use tadgs::scene::SceneConfig;
use tadgs::systems::adam::{BETA1, BETA2};
use tadgs::train::Trainer;

/// The demo scene at 128×96 over 6 frames, 2 anchors × 1001 random points: a count that is no
/// multiple of four, so most parameter sections of the resident buffers start inside a quad of
/// the Adam kernel (`shaders/adam.wgsl`), which must leave the neighbouring section's values
/// as they were.
fn small_scene() -> (SceneConfig, Arc<Dataset>) {
    demo::small_demo("pipeline", 6, 128, 96, 1001)
}

/// A CPU trainer and one whose world holds a `GpuTraining` on `gpu` (so the resident systems
/// run), both from the same Gaussians at SH degree 3.
fn trainers(config: &SceneConfig, dataset: &Arc<Dataset>, gpu: &GpuContext) -> [Trainer; 2] {
    let mut pair = [
        Trainer::new(config, dataset.clone()),
        Trainer::new(config, dataset.clone()),
    ];
    pair[1]
        .world
        .insert_resource(GpuTraining::with_context(gpu.clone()));
    for t in &mut pair {
        t.world.resource_mut::<TrainState>().sh_degree = 3;
    }
    pair
}

/// Values, m, v and gradient of component `P` of every Gaussian, in entity order.
fn group<P: Param>(world: &mut World) -> [Vec<f32>; 4] {
    let mut rows: Vec<(Entity, P, Adam<P>, Grad<P>)> = world
        .query::<(Entity, &P, &Adam<P>, &Grad<P>)>()
        .iter(world)
        .map(|(e, p, a, g)| (e, *p, *a, *g))
        .collect();
    rows.sort_by_key(|r| r.0);
    let mut out: [Vec<f32>; 4] = Default::default();
    for (_, p, a, g) in rows {
        out[0].extend_from_slice(p.values());
        out[1].extend_from_slice(a.m().values());
        out[2].extend_from_slice(a.v().values());
        out[3].extend_from_slice(g.0.values());
    }
    out
}

fn groups(world: &mut World) -> Vec<(&'static str, [Vec<f32>; 4])> {
    vec![
        ("position", group::<Position>(world)),
        ("fourier", group::<Fourier>(world)),
        ("temporal", group::<Temporal>(world)),
        ("opacity", group::<Opacity>(world)),
        ("rotation", group::<Rotation>(world)),
        ("scale", group::<Scale>(world)),
        ("color", group::<Color>(world)),
        ("color_rest", group::<ColorRest>(world)),
    ]
}

/// Largest error of `gpu` against `cpu` as a fraction of `rel · |cpu| + rel · max |cpu|`.
fn worst_ratio(name: &str, cpu: &[f32], gpu: &[f32], rel: f32) -> f32 {
    assert_eq!(cpu.len(), gpu.len(), "{name}: lengths");
    let largest = cpu.iter().fold(0f32, |m, v| m.max(v.abs()));
    let mut worst = 0f32;
    for (i, (c, g)) in cpu.iter().zip(gpu).enumerate() {
        let tol = rel * c.abs() + rel * largest + 1e-30;
        let err = (c - g).abs();
        assert!(err <= tol, "{name}[{i}]: GPU {g} vs CPU {c}");
        worst = worst.max(err / tol);
    }
    worst
}

/// After a sync, the `Grad<P>` and `Deformed` components (which the resident iteration does
/// not write) hold the last iteration's values, as on the CPU.
fn compare_synced_components(cpu: &mut World, gpu: &mut World) -> f32 {
    fn pair<P: Param>(cpu: &mut World, gpu: &mut World) -> (String, Vec<f32>, Vec<f32>) {
        let values = |world: &mut World| -> Vec<f32> {
            let grads: Vec<Grad<P>> = in_entity_order(world);
            grads.iter().flat_map(|g| g.0.values().to_vec()).collect()
        };
        (format!("Grad<{}>", P::NAME), values(cpu), values(gpu))
    }
    let grads = [
        pair::<Position>(cpu, gpu),
        pair::<Fourier>(cpu, gpu),
        pair::<Temporal>(cpu, gpu),
        pair::<Opacity>(cpu, gpu),
        pair::<Rotation>(cpu, gpu),
        pair::<Scale>(cpu, gpu),
        pair::<Color>(cpu, gpu),
        pair::<ColorRest>(cpu, gpu),
    ];
    let mut worst = 0f32;
    for (name, c, g) in &grads {
        assert!(
            c.iter().any(|v| *v != 0.0) || name == &format!("Grad<{}>", Rotation::NAME),
            "{name}: some gradient"
        );
        worst = worst.max(worst_ratio(name, c, g, 1e-4));
    }
    // Deformed values agree to f32 rounding of the same formulas (tests/gpu_deform.rs): the
    // opacity of every Gaussian, the rest where the CPU drew it (its deformation stage leaves
    // the geometry of Gaussians too faded to draw at `Deformed::faded`).
    let (c, g): (Vec<Deformed>, Vec<Deformed>) = in_entity_order::<Deformed>(cpu)
        .into_iter()
        .zip(in_entity_order::<Deformed>(gpu))
        .map(|(c, g)| {
            if c == Deformed::faded(c.opacity) {
                (c, Deformed::faded(g.opacity))
            } else {
                (c, g)
            }
        })
        .unzip();
    let (c, g): (&[f32], &[f32]) = (bytemuck::cast_slice(&c), bytemuck::cast_slice(&g));
    worst.max(worst_ratio("Deformed", c, g, 1e-5))
}

fn stats(world: &mut World) -> Vec<GradAccum> {
    in_entity_order(world)
}

/// Largest |a − b| over the two renders of the last iteration.
fn render_error(cpu: &World, gpu: &World) -> f32 {
    let (c, g) = (
        &cpu.resource::<SplatBuffers>().render.image,
        &gpu.resource::<SplatBuffers>().render.image,
    );
    assert_eq!(c.data.len(), g.data.len());
    c.data
        .iter()
        .zip(&g.data)
        .flat_map(|(a, b)| (0..3).map(move |ch| (a[ch] - b[ch]).abs()))
        .fold(0.0, f32::max)
}

/// Compares the Adam state and statistics after the first step (see the module docs).
/// Returns the worst ratios of error to tolerance (gradients, statistics) and the flips.
fn compare_first_step(cpu: &mut World, gpu: &mut World) -> (f32, f32, usize) {
    let mut worst = 0f32;
    let mut flips = 0;
    let mut largest_position_grad = 0f32;
    for ((name, c), (_, g)) in groups(cpu).into_iter().zip(groups(gpu)) {
        let grad_c = &c[3];
        let largest = grad_c.iter().fold(0f32, |m, v| m.max(v.abs()));
        if name == "position" {
            largest_position_grad = largest;
        }
        assert!(largest > 0.0 || name == "rotation", "{name}: some gradient");
        for i in 0..grad_c.len() {
            let tol = 1e-4 * grad_c[i].abs() + 1e-4 * largest + 1e-30;
            let grad_g = g[3][i];
            let err = (grad_g - grad_c[i]).abs();
            worst = worst.max(err / tol);
            assert!(
                err <= tol,
                "{name}[{i}]: gradient GPU {grad_g} vs CPU {}",
                grad_c[i]
            );
            // The moments as the gradients give them, to the gradient bound plus the spacing
            // of the CPU's bfloat16 moments (2⁻⁷ relative at most) and the GPU's, rounded to
            // nearest when read back.
            let moments = [
                (c[1][i] / (1.0 - BETA1), g[1][i] / (1.0 - BETA1)),
                (
                    (c[2][i] / (1.0 - BETA2)).sqrt(),
                    (g[2][i] / (1.0 - BETA2)).sqrt(),
                ),
            ];
            for (moment_c, moment_g) in moments {
                let spacing = 1.5 / 128.0 * moment_c.abs();
                assert!(
                    (moment_g - moment_c).abs() <= tol + spacing,
                    "{name}[{i}]: moments GPU {moment_g} vs CPU {moment_c}"
                );
            }
            let (pc, pg) = (c[0][i], g[0][i]);
            if (pc - pg).abs() > 1e-6 * (1.0 + pc.abs()) {
                assert!(
                    grad_c[i].abs() <= tol,
                    "{name}[{i}]: parameter GPU {pg} vs CPU {pc} with gradient {}",
                    grad_c[i]
                );
                flips += 1;
            }
        }
    }
    let (sc, sg) = (stats(cpu), stats(gpu));
    let mut worst_stats = 0f32;
    let grad_tol = 1e-4 * largest_position_grad;
    for (i, (c, g)) in sc.iter().zip(&sg).enumerate() {
        assert_eq!(c.count, g.count, "statistics {i}: {c:?} vs {g:?}");
        let checks = [
            (c.weight, g.weight, 1e-4 * c.weight.abs() + 1e-7),
            (
                c.lifespan_sum,
                g.lifespan_sum,
                1e-4 * c.lifespan_sum.abs() + 1e-7,
            ),
            (c.max_radius, g.max_radius, 1e-3 * c.max_radius.abs() + 1e-5),
            (
                c.weighted_grad,
                g.weighted_grad,
                1e-4 * c.weighted_grad.abs() + 1e-3 * grad_tol + 1e-12,
            ),
        ];
        for (a, b, tol) in checks {
            worst_stats = worst_stats.max((a - b).abs() / tol);
            assert!(
                (a - b).abs() <= tol,
                "statistics {i}: GPU {g:?} vs CPU {c:?}"
            );
        }
    }
    assert!(
        sc.iter().filter(|s| s.count > 0).count() > 100,
        "Gaussians were seen"
    );
    (worst, worst_stats, flips)
}

/// One training iteration through the resident chain equals the CPU schedule's (with the
/// float-atomic backward where the adapter offers it).
#[test]
fn one_resident_iteration_equals_the_cpu_schedule() {
    if let Some(ctx) = gpu::open_or_skip(|| GpuContext::new(true)) {
        resident_iteration_equals_the_cpu_schedule(&ctx);
    }
}

/// The same with the portable backward (per-tile sums; `train.gpu_float_atomics: false`).
#[test]
fn one_resident_iteration_on_the_portable_backward_equals_the_cpu_schedule() {
    if let Some(ctx) = gpu::open_or_skip(|| GpuContext::new(false)) {
        let training = GpuTraining::with_context(ctx.clone());
        assert!(training.describe().contains("per-tile sums"));
        resident_iteration_equals_the_cpu_schedule(&ctx);
    }
}

fn resident_iteration_equals_the_cpu_schedule(ctx: &GpuContext) {
    let (config, dataset) = small_scene();
    let [mut cpu, mut gpu] = trainers(&config, &dataset, ctx);
    let start = Instant::now();
    cpu.step();
    let cpu_time = start.elapsed();
    let start = Instant::now();
    gpu.step();
    let gpu_time = start.elapsed();
    assert!(gpu.fault().is_none() && cpu.fault().is_none());
    let count = cpu.gaussian_count();
    let image = render_error(&cpu.world, &gpu.world);
    let loss = (cpu.state().loss.total - gpu.state().loss.total).abs();
    gpu.sync();
    let (grads, stats, flips) = compare_first_step(&mut cpu.world, &mut gpu.world);
    let synced = compare_synced_components(&mut cpu.world, &mut gpu.world);
    eprintln!("synced Grad<P> and Deformed components ≤ {synced:.3} of tolerance");
    eprintln!(
        "{count} Gaussians: render error {image:.2e}, loss error {loss:.2e}, gradient error \
         ≤ {grads:.3} of tolerance, statistics ≤ {stats:.3}, {flips} first-step sign flips; \
         first iteration CPU {cpu_time:?}, GPU {gpu_time:?} (pipelines, first upload)"
    );
    assert!(image <= 1e-4, "render differs by {image}");
    // Later iterations: steady-state timings.
    let (mut cpu_time, mut gpu_time) = (std::time::Duration::ZERO, std::time::Duration::ZERO);
    for _ in 0..3 {
        let start = Instant::now();
        cpu.step();
        cpu_time += start.elapsed();
        let start = Instant::now();
        gpu.step();
        gpu_time += start.elapsed();
    }
    eprintln!(
        "per iteration over 3 more: CPU {:?}, GPU-resident {:?}",
        cpu_time / 3,
        gpu_time / 3
    );
}

/// Without VAD the 3DGS count (`densify.baseline_views: InFrustum`, the default) also counts
/// the Gaussians that have faded out of the view (σ(t) < 1/255) inside its frustum: after one
/// resident iteration the statistics equal the CPU's as in the test above, and far more
/// Gaussians are counted than drawn (a view at frame 1 with lifespans of ±1 frame: the
/// Gaussians of anchor 0 are drawn, those of anchors 3 and 5 have faded out).
#[test]
fn resident_baseline_counts_faded_gaussians_like_the_cpu() {
    let Some(ctx) = gpu::open_or_skip(|| GpuContext::new(true)) else {
        return;
    };
    let (mut config, dataset) = small_scene();
    config.densify.vad = false;
    config.densify.tat = false;
    config.model.tow.enabled = false;
    config.init.lifespan_half_frames = 1.0;
    let [mut cpu, mut gpu] = trainers(&config, &dataset, &ctx);
    let at_frame_1 = dataset.train.iter().position(|v| v.frame == 1).unwrap();
    for trainer in [&mut cpu, &mut gpu] {
        *trainer.world.resource_mut::<ViewOrder>() = ViewOrder {
            order: vec![at_frame_1],
            next: 0,
            ..ViewOrder::default()
        };
    }
    cpu.step();
    gpu.step();
    gpu.sync();
    compare_first_step(&mut cpu.world, &mut gpu.world);
    let drawn = cpu
        .world
        .resource::<SplatBuffers>()
        .splats
        .iter()
        .filter(|s| s.visible)
        .count();
    let counted = stats(&mut cpu.world).iter().filter(|s| s.count > 0).count();
    assert!(counted > drawn + 100, "{counted} counted, {drawn} drawn");
}

/// Six iterations with densification at 3 and 6 (read back, CPU clone/split/prune, upload)
/// run on the resident chain and track the CPU run: the same population sizes (to 0.5 %),
/// renders within 1e-2 (worst seen 1.8e-3) and losses within 1e-4 relative at every step,
/// and at the end at most 1 % of parameter values differing by more than 1e-3 (5 % of the
/// rotations).
#[test]
fn resident_training_with_densification_tracks_the_cpu() {
    let Some(ctx) = gpu::open_or_skip(|| GpuContext::new(true)) else {
        return;
    };
    let (mut config, dataset) = small_scene();
    config.train.iterations = 6;
    config.densify.from_iter = 2;
    config.densify.interval = 3;
    config.densify.grad_threshold = 2e-5;
    let [mut cpu, mut gpu] = trainers(&config, &dataset, &ctx);
    let initial = cpu.gaussian_count();
    for step in 1..=6 {
        cpu.step();
        gpu.step();
        assert!(gpu.fault().is_none(), "step {step}: {:?}", gpu.fault());
        let image = render_error(&cpu.world, &gpu.world);
        let (lc, lg) = (cpu.state().loss.total, gpu.state().loss.total);
        let (nc, ng) = (cpu.gaussian_count(), gpu.gaussian_count());
        eprintln!(
            "step {step}: {nc} vs {ng} Gaussians, render error {image:.2e}, loss {lc} vs {lg}"
        );
        // Renders drift apart through first-step sign flips (see the module docs): each
        // moves a parameter by 2·lr.
        assert!(image <= 1e-2, "step {step}: render differs by {image}");
        assert!(
            (lc - lg).abs() <= 1e-4 * lc,
            "step {step}: loss {lc} vs {lg}"
        );
        let allowed = nc / 200;
        assert!(
            nc.abs_diff(ng) <= allowed,
            "step {step}: {nc} vs {ng} Gaussians"
        );
    }
    assert!(
        cpu.gaussian_count() > initial,
        "densification added Gaussians"
    );
    gpu.sync();
    let (pc, pg) = (groups(&mut cpu.world), groups(&mut gpu.world));
    if cpu.gaussian_count() == gpu.gaussian_count() {
        for ((name, c), (_, g)) in pc.iter().zip(&pg) {
            let diff = c[0]
                .iter()
                .zip(&g[0])
                .filter(|(a, b)| (*a - *b).abs() > 1e-3 * (1.0 + a.abs()))
                .count();
            eprintln!(
                "{name}: {diff} of {} values differ by more than 1e-3",
                c[0].len()
            );
            // The rotations' first gradients are near zero (the Gaussians start isotropic), so
            // their Adam steps follow signs that any rounding decides: the CPU's bfloat16
            // moments against the GPU's f32 ones part 2.6–2.9 % of them by a step.
            let allowed = if *name == "rotation" { 20 } else { 100 };
            assert!(
                diff <= c[0].len() / allowed + 1,
                "{name}: {diff} values differ"
            );
        }
    }
}

/// The gradient check reports the first non-finite gradient: an infinite dL/dcolour under the
/// splats reaches their parameter gradients, and the check names the first one
/// (`systems::resident::resident_backward` turns the report into the schedule's
/// `NumericFault`, which stops Adam); so does a NaN.
#[test]
fn non_finite_gradients_are_caught() {
    let Some(ctx) = gpu::open_or_skip(|| GpuContext::new(true)) else {
        return;
    };
    let (mut training, out) = resident_after_clean_backward(&ctx);
    let mut d_color = vec![[1e-3f32; 3]; out.alpha.len()];
    // An infinite, then a NaN gradient at every pixel that shows a splat reaches the
    // parameter gradients of the splats under them (±inf or NaN: inf·0, inf − inf), and the
    // check names the first one. Float comparisons in the kernels are ordered, so a NaN
    // skipped by a `!=` test would be lost here.
    for bad in [f32::INFINITY, f32::NAN] {
        for (d, a) in d_color.iter_mut().zip(&out.alpha) {
            if *a > 0.01 {
                d[1] = bad;
            }
        }
        let fault = training.backward(&d_color).unwrap();
        let mut grads = tadgs::gpu::ParamGradients::default();
        training.read_gradients(&mut grads).unwrap();
        let first = grads
            .position
            .iter()
            .position(|g| !g.0.values().iter().all(|v| v.is_finite()));
        eprintln!("dL/dcolour {bad}: {fault:?}; first non-finite position gradient {first:?}");
        let first = first.expect("the bad dL/dcolour reaches the position gradients");
        assert_eq!(
            fault,
            Some(tadgs::gpu::GradientFault {
                group: Position::NAME,
                gaussian: first
            }),
            "the first non-finite gradient is reported"
        );
    }
}

/// The check names the exact value: one NaN or infinity planted at chosen places of otherwise
/// finite gradients (first and last value of the buffer, a Gaussian's first value inside a quad
/// that starts in the Gaussian before it, a later section while an earlier one is clean) is
/// reported with its section and Gaussian; with two planted, the earlier one.
#[test]
fn gradient_check_reports_the_first_non_finite_value() {
    let Some(ctx) = gpu::open_or_skip(|| GpuContext::new(true)) else {
        return;
    };
    let (mut training, _) = resident_after_clean_backward(&ctx);
    let n = training.len();
    let mut finite = Vec::new();
    training.read_gradient_values(&mut finite).unwrap();
    assert!(finite.iter().all(|g| g.is_finite()));
    let len = finite.len();
    assert_eq!(len, n * tadgs::layout::PARAM_FLOATS);
    let fault_at = |index: usize| {
        let mut start = 0;
        for (k, width) in tadgs::layout::WIDTHS.into_iter().enumerate() {
            if index < start + width * n {
                return tadgs::gpu::GradientFault {
                    group: tadgs::layout::SECTION_NAMES[k],
                    gaussian: (index - start) / width,
                };
            }
            start += width * n;
        }
        unreachable!()
    };
    // Position values are three per Gaussian: value 3 (Gaussian 1) shares quad 0 with Gaussian 0.
    let cases: [&[usize]; 7] = [
        &[0],
        &[3],
        &[7],
        &[3 * n + 5],
        &[len - 1],
        &[len - 1, 10],
        &[4 * n + 2, 4 * n + 1],
    ];
    for (case, planted) in cases.into_iter().enumerate() {
        let mut grads = finite.clone();
        for (k, &index) in planted.iter().enumerate() {
            grads[index] = if (case + k) % 2 == 0 {
                f32::NAN
            } else {
                f32::NEG_INFINITY
            };
        }
        training.write_gradient_values(&grads);
        let first = *planted.iter().min().unwrap();
        assert_eq!(
            training.check_gradients().unwrap(),
            Some(fault_at(first)),
            "values {planted:?} made non-finite"
        );
    }
    training.write_gradient_values(&finite);
    assert_eq!(training.check_gradients().unwrap(), None);
}

/// The small scene's CPU world uploaded by hand into a resident GPU pipeline, after one forward
/// pass at the world's sampled view and a backward pass of a small finite dL/dcolour (which
/// finds every gradient finite).
fn resident_after_clean_backward(ctx: &GpuContext) -> (GpuTraining, tadgs::raster::RenderOutput) {
    let (config, dataset) = small_scene();
    let [mut cpu, _] = trainers(&config, &dataset, ctx);
    // The resident state of the CPU world, uploaded by hand.
    let world = &mut cpu.world;
    let mut state = ResidentState::default();
    let mut sections: [[Vec<f32>; 3]; 7] = Default::default();
    let groups = groups(world);
    for (k, g) in groups.iter().take(6).enumerate() {
        let [values, m, v, _] = &g.1;
        sections[k] = [values.clone(), m.clone(), v.clone()];
    }
    // The GPU's colour section holds every SH band of a Gaussian together: DC, then the rest.
    let (dc, rest) = (&groups[6].1, &groups[7].1);
    for kind in 0..3 {
        for (dc, rest) in dc[kind].chunks(3).zip(rest[kind].chunks(45)) {
            sections[6][kind].extend_from_slice(dc);
            sections[6][kind].extend_from_slice(rest);
        }
    }
    for (kind, out) in [&mut state.params, &mut state.m, &mut state.v]
        .into_iter()
        .enumerate()
    {
        for s in &sections {
            out.extend_from_slice(&s[kind]);
        }
    }
    state.accum = stats(world);
    let mut warped: Vec<(Entity, WarpedTime)> = world
        .query::<(Entity, &WarpedTime)>()
        .iter(world)
        .map(|(e, w)| (e, *w))
        .collect();
    warped.sort_by_key(|r| r.0);
    let warped: Vec<WarpedTime> = warped.into_iter().map(|r| r.1).collect();
    let mut training = GpuTraining::with_context(ctx.clone());
    training.upload(&state).unwrap();
    let settings = world.resource::<Settings>().clone();
    let sample = *world.resource::<ViewSample>();
    let deform = DeformSettings::new(&settings, world.resource::<TrainState>());
    let mut out = Default::default();
    training
        .forward(&warped, &sample.camera, &deform, [0.0; 3], &mut out)
        .unwrap();
    let d_color = vec![[1e-3f32; 3]; out.alpha.len()];
    assert_eq!(training.backward(&d_color).unwrap(), None);
    (training, out)
}
