//! Densification: visibility-aware gradient statistics (VAD), lifespan-aware thresholds (TAT),
//! clone / split / prune, opacity reset. The only stage that spawns or despawns Gaussians.

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;
use glam::{Quat, Vec2, Vec3};
use rand_distr::{Distribution, StandardNormal};

use crate::components::{
    Adam, Deformed, Fourier, Grad, GradAccum, MotionWeights, Opacity, Position, Rotation, Scale,
    SplatSlot, Temporal, WarpedTime, each_param,
};
use crate::model::deform::{
    fourier_offset, lifespan_fraction, logit, rotation_at, scale_velocity, sigmoid,
};
use crate::model::project::in_frustum;
use crate::raster::{Splat, SplatGrad};
use crate::resources::{
    DensifyReport, Rng, Settings, SharedMotion, SplatBuffers, TrainState, ViewSample,
};
use crate::scene::{BaselineViews, CapPolicy, CloneTime, DensifyConfig, TatForm};

/// Children of a split have their scales divided by this.
pub const SPLIT_SCALE_DIVISOR: f32 = 1.6;
/// Opacity reset ceiling: σ^s ← min(σ^s, 0.01).
pub const OPACITY_RESET: f32 = 0.01;
/// `prune_big`: screen radius limit in pixels.
pub const PRUNE_SCREEN_RADIUS: f32 = 20.0;
/// `prune_big`: world scale limit as a fraction of the scene extent.
pub const PRUNE_WORLD_SCALE: f32 = 0.1;

/// The gradient sample of one splat in one view: the norm of dL/d(2D mean) in NDC units (the
/// image spans [−1, 1], so one pixel is 2/W by 2/H; `half_size` is (W/2, H/2)); 0 when the
/// splat was not visible. The GPU backward kernel (`shaders/param_backward.wgsl`) computes the
/// same for `shaders/stats.wgsl`.
pub fn ndc_gradient_norm(splat: &Splat, grad: &SplatGrad, half_size: Vec2) -> f32 {
    if splat.visible {
        (grad.mean2d * half_size).length()
    } else {
        0.0
    }
}

/// One view's gradient sample of a Gaussian, as the statistics take it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GradSample {
    /// g: the NDC norm of the 2D-mean gradient ([`ndc_gradient_norm`]).
    pub grad_norm: f32,
    /// σ(t): the Gaussian's opacity in the view.
    pub sigma: f32,
    /// ψ̄: its normalised lifespan.
    pub lifespan: f32,
    /// Δt = t − t_i: the view's time relative to the Gaussian's centre.
    pub offset: f32,
}

/// Adds one view's gradient sample to the statistics.
///
/// With VAD the sample is weighted by the Gaussian's opacity σ(t) in that view
/// (ḡ = Σσ(t)·g(t) / Σσ(t)); without it every visible view weighs 1 (the 3DGS mean).
pub fn accumulate(accum: &mut GradAccum, sample: GradSample, vad: bool) {
    let weight = if vad { sample.sigma } else { 1.0 };
    accum.weighted_grad += weight * sample.grad_norm;
    accum.weight += weight;
    accum.lifespan_sum += sample.lifespan;
    accum.count += 1;
    accum.weighted_offset += weight * sample.grad_norm * sample.offset;
}

/// The densification signal ḡ: weighted mean gradient (0 when never seen).
pub fn mean_gradient(accum: &GradAccum) -> f32 {
    if accum.weight > 0.0 {
        accum.weighted_grad / accum.weight
    } else {
        0.0
    }
}

/// The time the gradient came from: t_i + Σw·g·Δt / Σw·g, in [0, 1] (t_i when no gradient
/// reached the Gaussian).
pub fn gradient_time(accum: &GradAccum, center: f32) -> f32 {
    if accum.weighted_grad > 0.0 {
        (center + accum.weighted_offset / accum.weighted_grad).clamp(0.0, 1.0)
    } else {
        center
    }
}

/// The average normalised lifespan ψ̄ over the counted views (1 when never seen).
pub fn mean_lifespan(accum: &GradAccum) -> f32 {
    if accum.count > 0 {
        accum.lifespan_sum / accum.count as f32
    } else {
        1.0
    }
}

/// TAT: the threshold of a Gaussian with mean normalised lifespan ψ̄ ∈ [0, 1].
pub fn tat_threshold(form: TatForm, base: f32, lifespan: f32) -> f32 {
    let lifespan = lifespan.clamp(0.0, 1.0);
    match form {
        TatForm::Paper { beta, alpha } => {
            base * (1.0 / (1.0 + beta * (1.0 - lifespan))).powf(alpha)
        }
        TatForm::Implementation { beta, alpha } => {
            base * (beta + (1.0 - beta) * lifespan.powf(alpha))
        }
    }
}

/// Run condition: accumulate statistics while densification is still scheduled.
pub fn densifying(settings: Res<Settings>, state: Res<TrainState>) -> bool {
    state.iteration <= settings.densify.until_iter
}

/// Run condition: this iteration is a densification step.
pub fn densify_step(settings: Res<Settings>, state: Res<TrainState>) -> bool {
    is_densify_step(&settings.densify, state.iteration)
}

/// Whether iteration `i` clones, splits and prunes.
pub fn is_densify_step(d: &DensifyConfig, i: u32) -> bool {
    i > d.from_iter && i <= d.until_iter && i.is_multiple_of(d.interval.max(1))
}

/// Run condition: this iteration resets the opacities.
pub fn opacity_reset_step(settings: Res<Settings>, state: Res<TrainState>) -> bool {
    is_opacity_reset(
        &settings.densify,
        settings.train.iterations,
        state.iteration,
    )
}

/// Whether iteration `i` of a run of `iterations` resets the opacities: every
/// `opacity_reset_interval` up to `until_iter`, but never in the last 10 % of the run, which
/// would leave the model too few iterations to recover its opacities.
pub fn is_opacity_reset(densify: &DensifyConfig, iterations: u32, i: u32) -> bool {
    let interval = densify.opacity_reset_interval;
    interval > 0
        && i <= densify.until_iter
        && i % interval == 0
        && u64::from(i) * 10 <= u64::from(iterations) * 9
}

/// Whether the statistics also count the views that do not draw a Gaussian but whose frustum
/// holds it (faded out, σ(t) < 1/255, or only its faint fringe on the image): the 3DGS mean
/// gradient without VAD ([`BaselineViews::InFrustum`]).
pub fn counts_faded_views(densify: &DensifyConfig) -> bool {
    !densify.vad && densify.baseline_views == BaselineViews::InFrustum
}

/// Adds this iteration's view to the statistics of every Gaussian it counts for: those it
/// draws, and without VAD under [`BaselineViews::InFrustum`] also the others its frustum
/// holds (with gradient 0).
pub fn accumulate_stats(
    settings: Res<Settings>,
    sample: Res<ViewSample>,
    buffers: Res<SplatBuffers>,
    mut gaussians: Query<(
        &SplatSlot,
        &Deformed,
        &Temporal,
        &WarpedTime,
        &mut GradAccum,
    )>,
) {
    let vad = settings.densify.vad;
    let min_opacity = settings.densify.vad_min_opacity;
    let count_faded = counts_faded_views(&settings.densify);
    let (warp, model) = (settings.warp, settings.opacity);
    let (camera, near_plane) = (&sample.camera, settings.train.near_plane);
    // Whole table columns at a time (as the deformation does), and a Gaussian's deformed
    // state read only once its splat says it may count: most are not drawn.
    gaussians
        .contiguous_par_iter_mut()
        .expect("the statistics' components are stored in tables, so the query is dense")
        .for_each(|(slots, deformed, temporal, warped, mut accums)| {
            for (i, accum) in accums.iter_mut().enumerate() {
                let slot = slots[i].0 as usize;
                let splat = &buffers.splats[slot];
                if !splat.visible && !count_faded {
                    continue;
                }
                let deformed = &deformed[i];
                if min_opacity.is_some_and(|m| deformed.opacity <= m) {
                    continue;
                }
                let counted = splat.visible
                    || in_frustum(
                        Vec3::from_array(deformed.mean),
                        deformed.rotation,
                        Vec3::from_array(deformed.scale),
                        camera,
                        near_plane,
                    );
                if !counted {
                    continue;
                }
                let temporal = &temporal[i];
                let lifespan = lifespan_fraction(model, temporal.scale, temporal.center, &warp);
                let sample = GradSample {
                    grad_norm: buffers.ndc_grad_norm[slot],
                    sigma: deformed.opacity,
                    lifespan,
                    offset: warped[i].dt,
                };
                accumulate(accum, sample, vad);
                accum.max_radius = accum.max_radius.max(splat.extent.max_element());
            }
        });
}

/// What densification reads and edits of a Gaussian.
pub type DensifyItem<'a> = (
    Entity,
    &'a mut Position,
    &'a Rotation,
    &'a mut Scale,
    &'a Opacity,
    &'a mut GradAccum,
    (&'a Temporal, &'a Fourier),
);

/// A Gaussian that qualified for cloning or splitting, `strength` = ḡ / threshold (≥ 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Qualified {
    /// The Gaussian.
    pub entity: Entity,
    /// Its mean gradient ḡ divided by its threshold.
    pub strength: f32,
    /// Where its gradient came from in time ([`gradient_time`]).
    pub time: f32,
}

/// A Gaussian that may give up its place under [`CapPolicy::Replace`]: its spatial opacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Faint {
    /// The Gaussian.
    pub entity: Entity,
    /// Its spatial opacity σ^s.
    pub opacity: f32,
}

/// The parameters of a clone's parent that depend on its temporal centre.
#[derive(Clone, Copy)]
pub struct Parent<'a> {
    /// Canonical mean μ.
    pub position: &'a Position,
    /// Fourier motion.
    pub fourier: &'a Fourier,
    /// Temporal centre and scale.
    pub temporal: &'a Temporal,
    /// Rotation polynomial.
    pub rotation: &'a Rotation,
    /// Log-scale polynomial.
    pub scale: &'a Scale,
}

/// A copy of `parent` centred at time `time` (`densify.clone_time: Gradient`): at that time
/// its position, rotation and scale equal the parent's there, and its temporal opacity peaks
/// there with the parent's width. The motion keeps the parent's coefficients, so the copy
/// moves at first as the parent moves around its own centre.
pub fn recentred(
    parent: Parent,
    time: f32,
    settings: &Settings,
) -> (Position, Temporal, Rotation, Scale) {
    let dtw = settings
        .warp
        .apply(parent.temporal.center, time - parent.temporal.center);
    let (f, basis) = (parent.fourier, settings.motion_basis());
    let motion = |dtw| fourier_offset(&f.cos, &f.sin, &f.phase, basis, dtw);
    let mean = Vec3::from_array(parent.position.mean) + motion(dtw) - motion(0.0);
    let (r, s) = (parent.rotation, parent.scale);
    let velocity = scale_velocity(s.d1, settings.model.scale_motion);
    (
        Position {
            mean: mean.to_array(),
        },
        Temporal {
            center: time,
            ..*parent.temporal
        },
        Rotation {
            c0: std::array::from_fn(|k| r.c0[k] + r.c1[k] * dtw),
            c1: r.c1,
        },
        Scale {
            d0: std::array::from_fn(|k| s.d0[k] + velocity[k] * dtw),
            d1: s.d1,
        },
    )
}

/// Chooses which of the `qualified` Gaussians (in storage order) are densified when `room`
/// more fit under the cap, for the policies that look at all of them at once. Returns the
/// chosen ones in storage order and the faint Gaussians to prune to make room (`Replace`).
pub fn choose_under_cap(
    policy: CapPolicy,
    mut qualified: Vec<Qualified>,
    mut faint: Vec<Faint>,
    mut room: usize,
) -> (Vec<Qualified>, Vec<Faint>) {
    let mut replaced = Vec::new();
    if let CapPolicy::Replace { .. } = policy {
        let left_out = qualified.len().saturating_sub(room);
        if left_out > 0 {
            faint.sort_by(|a, b| a.opacity.total_cmp(&b.opacity));
            faint.truncate(left_out);
            room += faint.len();
            replaced = faint;
        }
    }
    if qualified.len() > room {
        // Strongest first; the sort is stable, so ties keep storage order.
        let mut order: Vec<usize> = (0..qualified.len()).collect();
        order.sort_by(|&a, &b| qualified[b].strength.total_cmp(&qualified[a].strength));
        order.truncate(room);
        order.sort_unstable();
        qualified = order.into_iter().map(|i| qualified[i]).collect();
    }
    (qualified, replaced)
}

/// Clones small and splits large Gaussians whose ḡ exceeds their threshold, prunes transparent
/// (and optionally oversized) ones, and resets the statistics. Where more qualify than the
/// population cap leaves room for, `densify.at_cap` decides which ones are densified.
pub fn densify_and_prune(
    mut commands: Commands,
    settings: Res<Settings>,
    mut state: ResMut<TrainState>,
    mut rng: ResMut<Rng>,
    mut gaussians: Query<DensifyItem>,
) {
    let d = &settings.densify;
    let extent = settings.extent;
    let mut report = DensifyReport {
        iteration: state.iteration,
        ..Default::default()
    };
    let mut population = gaussians.iter().len();
    let prune_big = d.prune_big && state.iteration > d.opacity_reset_interval;
    let replace_below = match d.at_cap {
        CapPolicy::Replace { max_opacity } => max_opacity,
        _ => 0.0,
    };
    // In storage order: the ones to densify (`InOrder`), or every one that qualified.
    let mut qualified = Vec::new();
    let mut faint = Vec::new();
    // Gaussians that qualified but were refused by the population cap.
    let mut capped = 0usize;
    for (entity, _, _, scale, opacity, mut accum, (temporal, _)) in gaussians.iter_mut() {
        let stats = std::mem::take(&mut *accum);
        let max_scale = Vec3::from_array(scale.d0).exp().max_element();
        let sigma = sigmoid(opacity.logit);
        let transparent = sigma < d.prune_opacity;
        let oversized = prune_big
            && (stats.max_radius > PRUNE_SCREEN_RADIUS || max_scale > PRUNE_WORLD_SCALE * extent);
        if transparent || oversized {
            commands.entity(entity).despawn();
            report.pruned += 1;
            population -= 1;
            continue;
        }
        let threshold = if d.tat {
            tat_threshold(d.tat_form, d.grad_threshold, mean_lifespan(&stats))
        } else {
            d.grad_threshold
        };
        let gradient = mean_gradient(&stats);
        if gradient < threshold {
            if sigma < replace_below {
                faint.push(Faint {
                    entity,
                    opacity: sigma,
                });
            }
            continue;
        }
        if d.at_cap == CapPolicy::InOrder {
            if population >= d.max_gaussians {
                capped += 1;
                continue;
            }
            population += 1;
        }
        qualified.push(Qualified {
            entity,
            strength: gradient / threshold,
            time: gradient_time(&stats, temporal.center),
        });
    }
    let mut replaced = 0;
    if d.at_cap != CapPolicy::InOrder {
        let room = d.max_gaussians.saturating_sub(population);
        let wanted = qualified.len();
        let (chosen, pruned) = choose_under_cap(d.at_cap, qualified, faint, room);
        for gaussian in &pruned {
            commands.entity(gaussian.entity).despawn();
        }
        replaced = pruned.len();
        report.pruned += replaced;
        capped = wanted - chosen.len();
        qualified = chosen;
    }
    for chosen in &qualified {
        let Ok((entity, mut position, rotation, mut scale, _, _, (temporal, fourier))) =
            gaussians.get_mut(chosen.entity)
        else {
            continue;
        };
        let max_scale = Vec3::from_array(scale.d0).exp().max_element();
        if max_scale <= d.percent_dense * extent {
            // Clone: an identical copy with fresh optimiser state.
            let mut parent_commands = commands.entity(entity);
            let mut clone = parent_commands.clone_and_spawn();
            if d.clone_time == CloneTime::Gradient {
                let parent = Parent {
                    position: &position,
                    fourier,
                    temporal,
                    rotation,
                    scale: &scale,
                };
                clone.insert(recentred(parent, chosen.time, &settings));
            }
            reset_optimizer(clone);
            report.cloned += 1;
        } else {
            // Split: the Gaussian and its copy move to two samples of itself, scales / 1.6.
            let sigma = Vec3::from_array(scale.d0).exp();
            // rotation_at normalises as rendering does (identity for a zero quaternion, which
            // Quat::normalize would turn into NaN positions).
            let [w, x, y, z] = rotation_at(rotation.c0, [0.0; 4], 0.0);
            let rot = Quat::from_xyzw(x, y, z, w);
            let mut sample = || {
                let n = Vec3::new(
                    StandardNormal.sample(&mut rng.0),
                    StandardNormal.sample(&mut rng.0),
                    StandardNormal.sample(&mut rng.0),
                );
                Vec3::from_array(position.mean) + rot * (sigma * n)
            };
            let (a, b) = (sample(), sample());
            position.mean = a.to_array();
            for s in &mut scale.d0 {
                *s -= SPLIT_SCALE_DIVISOR.ln();
            }
            reset_optimizer(commands.entity(entity));
            commands
                .entity(entity)
                .clone_and_spawn()
                .insert(Position { mean: b.to_array() });
            report.split += 1;
        }
    }
    if capped > 0 || replaced > 0 {
        tracing::info!(
            "iteration {}: population cap densify.max_gaussians = {} reached; {capped} \
             Gaussians were not cloned or split{}",
            state.iteration,
            d.max_gaussians,
            if replaced > 0 {
                format!(", {replaced} faint ones were pruned to make room")
            } else {
                String::new()
            }
        );
    }
    state.last_densify = report;
}

/// Zeroes the Adam moments of every parameter group the Gaussian has, and the gradients of
/// those that have gradient components (`train.fused_adam` spawns Gaussians without them).
fn reset_optimizer(mut gaussian: EntityCommands) {
    gaussian.queue(|mut entity: EntityWorldMut| {
        macro_rules! reset_every_group {
            ($($group:ty,)*) => {
                $(if entity.contains::<$group>() {
                    entity.insert(Adam::<$group>::default());
                }
                if entity.contains::<Grad<$group>>() {
                    entity.insert(Grad::<$group>::default());
                })*
            };
        }
        each_param!(reset_every_group);
        reset_every_group!(MotionWeights,);
    });
}

/// Standard deviation of a Gaussian's initial shared-motion weights (their mean is 0).
pub const MOTION_WEIGHT_INIT_STD: f32 = 0.1;

/// Gives every Gaussian without [`MotionWeights`] its weights of the shared motion bases
/// ([`SharedMotion`], `model.shared_motion`): the first B drawn from N(0, 0.1²) with the run's
/// RNG (in query order, so the same seed gives the same weights), the rest 0, with zero
/// gradient and Adam moments. Small non-zero weights give the bases a gradient from the first
/// iteration though they start at zero.
///
/// Runs when the world is built ([`crate::train::attach_motion_weights_now`]) and at the end of
/// every iteration, for Gaussians spawned without them (clones and split children inherit
/// their parent's).
pub fn attach_motion_weights(
    mut commands: Commands,
    shared: Res<SharedMotion>,
    mut rng: ResMut<Rng>,
    lacking: Query<Entity, (With<Position>, Without<MotionWeights>)>,
) {
    let bases = shared
        .bases
        .bases
        .min(crate::model::shared_motion::MAX_MOTION_BASES);
    for entity in &lacking {
        let mut weights = MotionWeights::default();
        for w in &mut weights.w[..bases] {
            let n: f32 = StandardNormal.sample(&mut rng.0);
            *w = MOTION_WEIGHT_INIT_STD * n;
        }
        commands.entity(entity).insert((
            weights,
            Grad::<MotionWeights>::default(),
            Adam::<MotionWeights>::default(),
        ));
    }
}

/// Caps every spatial opacity at 0.01 and clears its Adam moments.
pub fn reset_opacity(mut gaussians: Query<(&mut Opacity, &mut Adam<Opacity>)>) {
    let cap = logit(OPACITY_RESET);
    gaussians
        .par_iter_mut()
        .for_each(|(mut opacity, mut adam)| {
            opacity.logit = opacity.logit.min(cap);
            *adam = Adam::default();
        });
}

/// The densification systems both backends share, with their run conditions: the only
/// structural changes. Each backend adds its statistics (and, on the GPU, the read-back of the
/// components) before them.
pub fn densify_systems() -> ScheduleConfigs<ScheduleSystem> {
    (
        densify_and_prune.run_if(densify_step),
        reset_opacity.run_if(opacity_reset_step),
        attach_motion_weights.run_if(resource_exists::<SharedMotion>),
    )
        .chain()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn qualified(strengths: &[f32]) -> Vec<Qualified> {
        strengths
            .iter()
            .enumerate()
            .map(|(i, &strength)| Qualified {
                time: 0.0,
                entity: Entity::from_raw_u32(i as u32).unwrap(),
                strength,
            })
            .collect()
    }

    fn faint(opacities: &[f32]) -> Vec<Faint> {
        opacities
            .iter()
            .enumerate()
            .map(|(i, &opacity)| Faint {
                entity: Entity::from_raw_u32(100 + i as u32).unwrap(),
                opacity,
            })
            .collect()
    }

    /// With room for all, every policy densifies every qualifying Gaussian and replaces none.
    #[test]
    fn below_the_cap_every_qualifying_gaussian_is_chosen() {
        let all = qualified(&[1.5, 3.0, 1.1]);
        for policy in [
            CapPolicy::Strongest,
            CapPolicy::Replace { max_opacity: 0.1 },
        ] {
            let (chosen, replaced) = choose_under_cap(policy, all.clone(), faint(&[0.01]), 3);
            assert_eq!(chosen, all);
            assert!(replaced.is_empty());
        }
    }

    /// `Strongest` gives the room to the largest ḡ / threshold, keeps storage order among the
    /// chosen, and breaks ties by storage order.
    #[test]
    fn strongest_takes_the_largest_ratios_in_storage_order() {
        let all = qualified(&[1.5, 3.0, 1.1, 2.0, 2.0, 1.2]);
        let (chosen, replaced) = choose_under_cap(CapPolicy::Strongest, all.clone(), vec![], 3);
        assert_eq!(chosen, vec![all[1], all[3], all[4]]);
        assert!(replaced.is_empty());
        let (chosen, _) = choose_under_cap(CapPolicy::Strongest, all.clone(), vec![], 2);
        assert_eq!(chosen, vec![all[1], all[3]]);
        let (chosen, _) = choose_under_cap(CapPolicy::Strongest, all, vec![], 0);
        assert!(chosen.is_empty());
    }

    /// `Replace` prunes the faintest Gaussians, no more than the qualifying ones left out, and
    /// gives their places to the strongest of those.
    #[test]
    fn replace_prunes_the_faintest_for_the_ones_left_out() {
        let all = qualified(&[1.5, 3.0, 1.1, 2.0]);
        let candidates = faint(&[0.04, 0.01, 0.03]);
        let policy = CapPolicy::Replace { max_opacity: 0.05 };
        // No room: all three faint ones go, faintest first, and the weakest stays out.
        let (chosen, replaced) = choose_under_cap(policy, all.clone(), candidates.clone(), 0);
        assert_eq!(replaced, vec![candidates[1], candidates[2], candidates[0]]);
        assert_eq!(chosen, vec![all[0], all[1], all[3]]);
        // Room for three: one faint one is enough.
        let (chosen, replaced) = choose_under_cap(policy, all.clone(), candidates.clone(), 3);
        assert_eq!(replaced, vec![candidates[1]]);
        assert_eq!(chosen, all);
        // Fewer faint Gaussians than left out.
        let (chosen, replaced) = choose_under_cap(policy, all.clone(), candidates[..1].to_vec(), 2);
        assert_eq!(replaced, vec![candidates[0]]);
        assert_eq!(chosen, vec![all[0], all[1], all[3]]);
    }

    /// VAD equals the plain 3DGS mean when σ(t) = 1 in every view.
    #[test]
    fn vad_with_full_opacity_is_the_plain_mean() {
        let grads = [1e-4, 5e-4, 2e-4, 9e-4];
        let (mut vad, mut plain) = (GradAccum::default(), GradAccum::default());
        for g in grads {
            accumulate(&mut vad, sample(g, 1.0, 0.0), true);
            accumulate(&mut plain, sample(g, 0.37, 0.0), false);
        }
        let mean = grads.iter().sum::<f32>() / grads.len() as f32;
        assert!((mean_gradient(&vad) - mean).abs() < 1e-9);
        assert!((mean_gradient(&plain) - mean).abs() < 1e-9);
    }

    /// VAD is not diluted by views where the Gaussian is nearly invisible.
    #[test]
    fn vad_discounts_views_where_the_gaussian_is_faint() {
        let mut vad = GradAccum::default();
        let mut plain = GradAccum::default();
        for (g, sigma) in [(8e-4, 0.9), (0.0, 0.01), (0.0, 0.01), (0.0, 0.01)] {
            accumulate(&mut vad, sample(g, sigma, 0.0), true);
            accumulate(&mut plain, sample(g, sigma, 0.0), false);
        }
        assert!((mean_gradient(&plain) - 2e-4).abs() < 1e-9);
        assert!(mean_gradient(&vad) > 7.5e-4);
    }

    /// Without VAD, `InFrustum` counts a Gaussian that has faded out of a view it faces (with
    /// gradient 0, weight 1) and `Drawn` does not; neither counts one behind the camera, and
    /// with VAD both count only the drawn one.
    #[test]
    fn baseline_views_decide_whether_faded_gaussians_count() {
        use crate::components::{Temporal, WarpedTime};
        use crate::data::Camera;
        use crate::scene::{DataSource, SceneConfig};
        use crate::systems::splat::project_all;
        use bevy_ecs::system::RunSystemOnce;

        crate::train::init_task_pool();
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 64, 64, 1.0);
        let gaussian = |z: f32, opacity: f32| Deformed {
            mean: [0.0, 0.0, z],
            rotation: [1.0, 0.0, 0.0, 0.0],
            scale: [0.1; 3],
            opacity,
            color: [0.5; 3],
        };
        // Drawn; faded out (σ(t) < 1/255) in front of the camera; faded out behind it.
        let deformed = [gaussian(0.0, 0.5), gaussian(0.5, 1e-4), gaussian(6.0, 1e-4)];
        let mut splats = Vec::new();
        project_all(&deformed, &camera, 0.01, &mut splats);
        assert_eq!(
            splats.iter().map(|s| s.visible).collect::<Vec<_>>(),
            [true, false, false]
        );
        let counts = |vad: bool, views: BaselineViews| {
            let data = DataSource::Synthetic(crate::data::synthetic::demo_scene());
            let mut scene = SceneConfig::new("stats", data);
            scene.densify.vad = vad;
            scene.densify.baseline_views = views;
            scene.train.near_plane = 0.01;
            let mut world = World::new();
            world.insert_resource(Settings::new(&scene, 10, 2.0));
            world.insert_resource(ViewSample {
                camera,
                view: None,
                frame: 0,
                time: 0.5,
                background: scene.train.background,
            });
            world.insert_resource(SplatBuffers {
                splats: splats.clone(),
                ndc_grad_norm: vec![3e-4, 0.0, 0.0],
                ..Default::default()
            });
            let entities: Vec<Entity> = (0..3)
                .map(|slot| {
                    let temporal = Temporal {
                        center: 0.5,
                        ..Default::default()
                    };
                    let parts = (SplatSlot(slot), deformed[slot as usize], temporal);
                    world
                        .spawn((parts, WarpedTime::default(), GradAccum::default()))
                        .id()
                })
                .collect();
            world.run_system_once(accumulate_stats).unwrap();
            let accum = |e: Entity| *world.get::<GradAccum>(e).unwrap();
            let counts: Vec<u32> = entities.iter().map(|&e| accum(e).count).collect();
            // The drawn Gaussian's mean gradient is 3e-4 whatever is counted besides.
            assert!((mean_gradient(&accum(entities[0])) - 3e-4).abs() < 1e-9);
            counts
        };
        assert_eq!(counts(false, BaselineViews::InFrustum), [1, 1, 0]);
        assert_eq!(counts(false, BaselineViews::Drawn), [1, 0, 0]);
        assert_eq!(counts(true, BaselineViews::InFrustum), [1, 0, 0]);
        assert_eq!(counts(true, BaselineViews::Drawn), [1, 0, 0]);
    }

    fn sample(grad_norm: f32, sigma: f32, offset: f32) -> GradSample {
        GradSample {
            grad_norm,
            sigma,
            lifespan: 1.0,
            offset,
        }
    }

    /// The gradient's time is the w·g-weighted mean of the views' times, the centre when no
    /// gradient arrived, and stays in [0, 1].
    #[test]
    fn gradient_time_is_the_weighted_mean_of_the_views_times() {
        let center = 0.4;
        let mut accum = GradAccum::default();
        // Views at t = 0.5 (g 3e-4, σ 0.5) and t = 0.3 (g 1e-4, σ 0.5): weights 1.5e-4, 0.5e-4.
        accumulate(&mut accum, sample(3e-4, 0.5, 0.1), true);
        accumulate(&mut accum, sample(1e-4, 0.5, -0.1), true);
        // A view without gradient does not move it.
        accumulate(&mut accum, sample(0.0, 0.9, 0.5), true);
        let expected = (1.5e-4 * 0.5 + 0.5e-4 * 0.3) / 2e-4;
        assert!((gradient_time(&accum, center) - expected).abs() < 1e-6);
        assert_eq!(gradient_time(&GradAccum::default(), center), center);
        let mut late = GradAccum::default();
        accumulate(&mut late, sample(1e-4, 1.0, 0.9), true);
        assert_eq!(gradient_time(&late, center), 1.0);
    }

    /// A clone re-centred at t_g has, at t_g, the parent's position, rotation and scale (with
    /// TOW, a slow motion basis, per-frequency phases and scale motion), the parent's temporal
    /// width, and its centre at t_g.
    #[test]
    fn a_recentred_clone_matches_its_parent_at_the_new_centre() {
        use crate::model::deform::{MotionBasis, TemporalOpacity, scale_at};
        use crate::model::warp::TimeWarp;
        use crate::scene::{ModelConfig, PhaseModel, TrainConfig};
        let model = ModelConfig {
            phase: PhaseModel::PerFrequency,
            motion_period: 2.0,
            scale_motion: true,
            ..ModelConfig::default()
        };
        let settings = Settings {
            model,
            densify: DensifyConfig::default(),
            train: TrainConfig::default(),
            frame_count: 150,
            extent: 1.0,
            warp: TimeWarp::tow(50.0, 150, 0.75),
            opacity: TemporalOpacity::Rbf,
        };
        let position = Position {
            mean: [0.3, -1.2, 2.0],
        };
        let fourier = Fourier {
            cos: [
                [0.1, -0.2, 0.05],
                [0.02, 0.0, -0.04],
                [0.0; 3],
                [0.01, 0.01, 0.01],
            ],
            sin: [
                [-0.05, 0.1, 0.2],
                [0.0, 0.03, 0.0],
                [0.02, 0.0, 0.0],
                [0.0; 3],
            ],
            phase: [0.3, -1.0, 2.0, 0.5],
        };
        let temporal = Temporal {
            center: 0.4,
            scale: [2.5, 0.0],
        };
        let rotation = Rotation {
            c0: [0.9, 0.1, -0.2, 0.3],
            c1: [0.05, -0.3, 0.2, 0.1],
        };
        let scale = Scale {
            d0: [-3.0, -2.5, -4.0],
            d1: [0.4, -0.2, 0.1],
        };
        let basis: MotionBasis = settings.motion_basis();
        let pose = |p: &Position, f: &Fourier, t: &Temporal, r: &Rotation, s: &Scale, at: f32| {
            let dtw = settings.warp.apply(t.center, at - t.center);
            let mean =
                Vec3::from_array(p.mean) + fourier_offset(&f.cos, &f.sin, &f.phase, basis, dtw);
            (
                mean,
                rotation_at(r.c0, r.c1, dtw),
                scale_at(s.d0, s.d1, dtw),
            )
        };
        for time in [0.0, 0.25, 0.43, 0.9, 1.0] {
            let parent = Parent {
                position: &position,
                fourier: &fourier,
                temporal: &temporal,
                rotation: &rotation,
                scale: &scale,
            };
            let (p, t, r, s) = recentred(parent, time, &settings);
            assert_eq!(t.center, time);
            assert_eq!(t.scale, temporal.scale);
            let want = pose(&position, &fourier, &temporal, &rotation, &scale, time);
            let got = pose(&p, &fourier, &t, &r, &s, time);
            assert!(
                (want.0 - got.0).length() < 1e-5,
                "{time}: {want:?} vs {got:?}"
            );
            for k in 0..4 {
                assert!(
                    (want.1[k] - got.1[k]).abs() < 1e-5,
                    "{time}: {want:?} vs {got:?}"
                );
            }
            assert!((want.2 - got.2).abs().max_element() < 1e-5 * want.2.max_element());
        }
    }

    /// TAT equals τ_pos at full lifespan and decreases for shorter lifespans (both forms).
    #[test]
    fn tat_is_base_at_full_lifespan_and_lower_for_short_lived() {
        let paper = TatForm::Paper {
            beta: 0.3,
            alpha: 1.0,
        };
        assert!((tat_threshold(paper, 2e-4, 1.0) - 2e-4).abs() < 1e-12);
        assert!((tat_threshold(paper, 2e-4, 0.0) - 2e-4 / 1.3).abs() < 1e-10);
        let implementation = TatForm::Implementation {
            beta: 0.75,
            alpha: 0.8,
        };
        assert!((tat_threshold(implementation, 2e-4, 1.0) - 2e-4).abs() < 1e-12);
        assert!((tat_threshold(implementation, 2e-4, 0.0) - 1.5e-4).abs() < 1e-10);
        for form in [paper, implementation] {
            let mut last = f32::INFINITY;
            for i in (0..=10).rev() {
                let t = tat_threshold(form, 2e-4, i as f32 / 10.0);
                assert!(t <= last);
                last = t;
            }
            assert!(tat_threshold(form, 2e-4, 0.1) < tat_threshold(form, 2e-4, 0.9));
        }
    }
}
