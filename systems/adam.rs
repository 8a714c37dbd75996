//! Adam with per-group learning rates and exponential decay of the position learning rate.

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;

use crate::components::{
    Adam, AdamClock, Color, ColorRest, Fourier, Grad, MotionWeights, Opacity, Param, Position,
    Rotation, Scale, SplatSlot, Temporal, TimeWindow, WarpedTime, each_param,
};
use crate::model::deform::FOURIER_TERMS;
use crate::model::exposure::Exposure;
use crate::model::project::drawable;
use crate::model::sh::{SH_COEFFS, coeff_count};
use crate::model::shared_motion::MAX_MOTION_BASES;
use crate::resources::{
    CameraExposures, DeformEveryGaussian, Settings, SharedMotion, SplatBuffers, TrainState,
    ViewSample,
};
use crate::scene::LearningRates;
use crate::systems::deform::{faded_geometry_read, opacity_at};
use crate::systems::prefetch::{RowsAhead, prefetch};

pub use crate::model::adam::{BETA1, BETA2, EPSILON};
use crate::model::adam::{
    BiasCorrection, DeferredSums, StoredMoments, adam_update, adam_update_stored,
    deferred_update_stored, moment_seed,
};

/// Salts of [`moment_seed`]: the dense step and the catch-up of skipped steps round the stored
/// moments with different random bits.
const DENSE_STEP: u32 = 0;
const CATCH_UP: u32 = 0x5EED_CA7C;

/// A parameter group: how each of its values' learning rate is set.
pub trait ParamGroup: Param {
    /// Per-value learning rates, laid out like the component itself. `position_lr` is the
    /// current (decayed, extent-scaled) position learning rate.
    fn learning_rates(lr: &LearningRates, position_lr: f32) -> Self;

    /// How many leading values of the flat layout ([`Param::values`]) can have a non-zero
    /// gradient at SH degree `sh_degree`; Adam leaves the rest alone. Their gradients and
    /// moments are exactly zero, so skipping them changes nothing but the memory traffic.
    fn active_values(_sh_degree: u32) -> usize {
        std::mem::size_of::<Self>() / std::mem::size_of::<f32>()
    }

    /// Whether `train.deferred_adam` defers this group's momentum steps. The groups that
    /// decide whether a view can draw a Gaussian (its σ(t)) are stepped densely, so that the
    /// others can be brought up to date before it is drawn ([`catch_up_drawable`]).
    const DEFERRED: bool = true;
}

impl ParamGroup for Position {
    fn learning_rates(_: &LearningRates, position_lr: f32) -> Self {
        Self {
            mean: [position_lr; 3],
        }
    }
}

impl ParamGroup for Fourier {
    fn learning_rates(lr: &LearningRates, position_lr: f32) -> Self {
        let coeff = [[lr.fourier_cos_sin * position_lr; 3]; FOURIER_TERMS];
        Self {
            cos: coeff,
            sin: coeff,
            phase: [lr.fourier_phase * position_lr; FOURIER_TERMS],
        }
    }
}

impl ParamGroup for Temporal {
    const DEFERRED: bool = false;

    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        // The temporal centre stays at its anchor unless its rate is set.
        Self {
            center: lr.temporal_center,
            scale: [lr.temporal_scale; 2],
        }
    }
}

impl ParamGroup for Opacity {
    const DEFERRED: bool = false;

    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self { logit: lr.opacity }
    }
}

impl ParamGroup for Rotation {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self {
            c0: [lr.rotation; 4],
            c1: [lr.rotation_velocity; 4],
        }
    }
}

impl ParamGroup for Scale {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self {
            d0: [lr.scale; 3],
            d1: [lr.scale_velocity; 3],
        }
    }
}

impl ParamGroup for Color {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self { dc: [lr.sh_dc; 3] }
    }
}

impl ParamGroup for ColorRest {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self {
            sh: [[lr.sh_dc / lr.sh_rest_divisor; 3]; SH_COEFFS - 1],
        }
    }

    /// Coefficients above the active degree get no gradient (the basis is band by band).
    fn active_values(sh_degree: u32) -> usize {
        3 * (coeff_count(sh_degree) - 1)
    }
}

impl ParamGroup for MotionWeights {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        // The weights past the model's B never get a gradient, so their moments stay 0 and
        // Adam leaves them at 0.
        Self {
            w: [lr.motion_weights; MAX_MOTION_BASES],
        }
    }
}

/// Position learning rate at `iteration`: exponential interpolation from `position` to
/// `position_final` over the run, scaled by the scene extent.
pub fn position_lr(lr: &LearningRates, iteration: u32, iterations: u32, extent: f32) -> f32 {
    let t = (iteration as f32 / iterations.max(1) as f32).clamp(0.0, 1.0);
    (lr.position.ln() * (1.0 - t) + lr.position_final.ln() * t).exp() * extent
}

/// Learning rate of the shared motion bases at `iteration`: `motion_bases` × the scene extent,
/// decayed over the run in the same ratio as the position rate (`position_final / position`).
pub fn motion_bases_lr(lr: &LearningRates, iteration: u32, iterations: u32, extent: f32) -> f32 {
    let t = (iteration as f32 / iterations.max(1) as f32).clamp(0.0, 1.0);
    let decay = if lr.position > 0.0 {
        (lr.position_final / lr.position).powf(t)
    } else {
        1.0
    };
    lr.motion_bases * extent * decay
}

/// With `train.deferred_adam`, every Gaussian's skipped momentum steps are applied at
/// iterations that are multiples of this, at densification and opacity-reset steps and at the
/// last iteration (see [`catches_up`]).
pub const DEFERRED_CATCH_UP_INTERVAL: u32 = 100;

/// Whether iteration `iteration` brings every Gaussian up to date under
/// `train.deferred_adam`: a multiple of [`DEFERRED_CATCH_UP_INTERVAL`], a densification or
/// opacity-reset step (which read or reset parameters), or the run's last iteration. A pure
/// function of the settings and the iteration, so a resumed run catches up where the
/// uninterrupted one does. (Iterations past the last, as `tadgs bench` runs on a finished
/// run's checkpoint, catch up only at the multiples.)
pub fn catches_up(settings: &Settings, iteration: u32) -> bool {
    let densify = &settings.densify;
    iteration.is_multiple_of(DEFERRED_CATCH_UP_INTERVAL)
        || iteration == settings.train.iterations
        || crate::systems::densify::is_densify_step(densify, iteration)
        || crate::systems::densify::is_opacity_reset(densify, settings.train.iterations, iteration)
}

/// The last iteration before `iteration` that caught every Gaussian up (0 if none).
fn last_catch_up(settings: &Settings, iteration: u32) -> u32 {
    (1..iteration)
        .rev()
        .take(DEFERRED_CATCH_UP_INTERVAL as usize)
        .find(|&i| catches_up(settings, i))
        .unwrap_or(0)
}

/// What [`adam_step`] reads and writes of each Gaussian for group `P`.
type GroupState<P> = (
    &'static mut P,
    &'static Grad<P>,
    &'static mut Adam<P>,
    Option<&'static SplatSlot>,
    Option<&'static AdamClock>,
);

/// One Adam step on every Gaussian's `P`, with bias correction for the global step.
/// With `train.visible_adam`, Gaussians that received no gradient
/// ([`SplatBuffers::gradient_reached`]) are left as they are. With `train.deferred_adam` they
/// are left as they are too, but the momentum steps dense Adam would have given them are
/// applied in one update ([`DeferredSums`]) when they next receive a gradient and whenever
/// [`catches_up`] says so; [`AdamClock`] records how far each Gaussian is.
///
/// The query is walked in contiguous chunks (whole table columns), each read as flat `f32`
/// slices: stepping one entity at a time cost about as much again as the updates themselves
/// on a real run's population (see the README's Performance section).
pub fn adam_step<P: ParamGroup>(
    settings: Res<Settings>,
    state: Res<TrainState>,
    buffers: Option<Res<SplatBuffers>>,
    mut deferred: Local<DeferredSums>,
    mut params: Query<GroupState<P>>,
) {
    let step = GroupStep::<P>::new(&settings, &state, buffers.as_deref(), &mut deferred);
    params
        .contiguous_par_iter_mut()
        .expect("parameter components are stored in tables, so the query is dense")
        .for_each(|(mut values, grads, mut moments, slots, clocks)| {
            step.rows(&mut values, grads, &mut moments, slots, clocks);
        });
}

/// This iteration's Adam step of group `P`, as [`adam_step`] (and the fused pass,
/// [`crate::systems::fused`]) applies it to runs of consecutive Gaussians.
pub(crate) struct GroupStep<'a, P: ParamGroup> {
    iteration: u32,
    rates: P,
    active: usize,
    bias: BiasCorrection,
    seed: u32,
    /// Which slots received a gradient, when only those are stepped (visible or deferred
    /// Adam).
    reached: Option<&'a [bool]>,
    /// With deferred Adam: the sums of the dense steps since the last catch-up, and whether
    /// this iteration brings every Gaussian up to date.
    deferred: Option<(&'a DeferredSums, bool)>,
}

impl<'a, P: ParamGroup> GroupStep<'a, P> {
    /// The step of `state.iteration`; `sums` is the caller's own record of deferred steps for
    /// this group (brought up to date here when deferring). Without the splatting stage's
    /// `buffers` (a world that only optimises), every Gaussian counts as seen.
    pub(crate) fn new(
        settings: &Settings,
        state: &TrainState,
        buffers: Option<&'a SplatBuffers>,
        sums: &'a mut DeferredSums,
    ) -> Self {
        let iteration = state.iteration;
        let train = &settings.train;
        let defer = train.deferred_adam && P::DEFERRED;
        let reached = buffers
            .filter(|_| train.visible_adam || defer)
            .map(|b| b.gradient_reached.as_slice());
        let deferred = match reached {
            Some(_) if defer => {
                sums_through::<P>(sums, settings, iteration);
                Some((&*sums, catches_up(settings, iteration)))
            }
            _ => None,
        };
        Self {
            iteration,
            rates: rates_at::<P>(settings, iteration),
            active: P::active_values(state.sh_degree),
            bias: BiasCorrection::after(iteration.max(1) as i32),
            seed: moment_seed(iteration, DENSE_STEP),
            reached,
            deferred,
        }
    }

    /// Steps consecutive Gaussians of one table: their values, gradients and moments, and
    /// their slots and clocks where they have them.
    pub(crate) fn rows(
        &self,
        values: &mut [P],
        grads: &[Grad<P>],
        moments: &mut [Adam<P>],
        slots: Option<&[SplatSlot]>,
        clocks: Option<&[AdamClock]>,
    ) {
        let (iteration, bias, seed) = (self.iteration, self.bias, self.seed);
        let rates = &self.rates.values()[..self.active];
        let values: &mut [f32] = bytemuck::cast_slice_mut(values);
        let grads: &[f32] = bytemuck::cast_slice(grads);
        let moments: &mut [StoredMoments] = bytemuck::cast_slice_mut(moments);
        let (Some(reached), Some(slots)) = (self.reached, slots) else {
            adam_values(values, grads, moments, P::FLOATS, rates, bias, seed);
            return;
        };
        let floats = P::FLOATS;
        let mut coefficients = [0.0; MAX_GROUP_FLOATS];
        let coefficients = &mut coefficients[..rates.len()];
        let deferred = self.deferred;
        let all_catch_up = deferred.is_some_and(|(_, all)| all);
        let mut step_row =
            |values: &mut [f32], moments: &mut [StoredMoments], i: usize, seen: bool| {
                let x = &mut values[i * floats..(i + 1) * floats];
                let mv = &mut moments[i * floats..(i + 1) * floats];
                if let Some((sums, _)) = deferred {
                    // A Gaussian drawn this iteration was brought up to date before
                    // (`catch_up_drawable`), so `last` is the previous iteration.
                    let last = clocks.map_or(0, |c| c[i].0);
                    let through = if seen { iteration - 1 } else { iteration };
                    catch_up(x, mv, sums, last, through, coefficients);
                }
                if seen {
                    let g = &grads[i * floats..(i + 1) * floats];
                    adam_values(x, g, mv, floats, rates, bias, seed);
                }
            };
        // The Gaussians a view reaches lie scattered over the table: their rows are
        // prefetched a few seen rows ahead of the one being stepped, which otherwise
        // waits on a cache miss per row.
        let mut ahead = RowsAhead::default();
        for (i, slot) in slots.iter().enumerate() {
            let seen = reached.get(slot.0 as usize).is_some_and(|&r| r);
            if !seen && !all_catch_up {
                continue;
            }
            prefetch(&values[i * floats..(i + 1) * floats]);
            prefetch(&grads[i * floats..(i + 1) * floats]);
            prefetch(&moments[i * floats..(i + 1) * floats]);
            if let Some((row, seen)) = ahead.push(i, seen) {
                step_row(values, moments, row, seen);
            }
        }
        while let Some((row, seen)) = ahead.pop() {
            step_row(values, moments, row, seen);
        }
    }
}

/// The learning rates of group `P` at `iteration`.
fn rates_at<P: ParamGroup>(settings: &Settings, iteration: u32) -> P {
    let lr = &settings.train.rates_at(iteration);
    P::learning_rates(
        lr,
        position_lr(lr, iteration, settings.train.iterations, settings.extent),
    )
}

/// Brings `sums` (one system's, for group `P`) through `iteration`: they run from the last
/// catch-up, and fresh ones (a new or resumed run) start there.
fn sums_through<P: ParamGroup>(sums: &mut DeferredSums, settings: &Settings, iteration: u32) {
    let start = last_catch_up(settings, iteration);
    if sums.width() != P::FLOATS || sums.start() != start || sums.end() > iteration {
        *sums = DeferredSums::new(start, P::FLOATS);
    }
    while sums.end() < iteration {
        let next = sums.end() + 1;
        sums.push(rates_at::<P>(settings, next).values());
    }
}

/// Applies to one Gaussian's values `x` and moments `mv` (first then second, as in
/// [`Adam`]) the momentum steps of dense Adam after step `last` through `through`, where
/// `last` is clamped into the span of `sums` (which must reach `through`); only the first
/// `coefficients.len()` values (the active ones) move.
#[inline]
fn catch_up(
    x: &mut [f32],
    mv: &mut [StoredMoments],
    sums: &DeferredSums,
    last: u32,
    through: u32,
    coefficients: &mut [f32],
) {
    let last = last.clamp(sums.start(), through);
    if last == through {
        return;
    }
    sums.coefficients(last, through, coefficients);
    let (decay, epsilon) = (sums.decay(through - last), sums.epsilon(last));
    let seed = moment_seed(through, CATCH_UP);
    for ((x, mv), &c) in x.iter_mut().zip(mv).zip(&*coefficients) {
        deferred_update_stored(x, mv, c, epsilon, decay, seed);
    }
}

/// Marks, in [`AdamClock`]'s top bit, a Gaussian [`mark_drawable_behind`] found behind and
/// drawable, for the catch-up systems; [`clock_drawable`] clears it in the same stage.
const BEHIND: u32 = 1 << 31;

/// Under `train.deferred_adam`, first of the catch-up before the deformation: marks each
/// Gaussian the view can draw (its σ(t) at the view's time, from the densely stepped opacity
/// and temporal groups; every Gaussian where a stage reads faded ones' geometry) that is not
/// up to date through the previous iteration, by the top bit of its [`AdamClock`], so that the
/// per-group [`catch_up_drawable`] read only the clocks.
#[allow(clippy::type_complexity)]
pub fn mark_drawable_behind(
    settings: Res<Settings>,
    state: Res<TrainState>,
    sample: Res<ViewSample>,
    every_gaussian: Option<Res<DeformEveryGaussian>>,
    mut gaussians: Query<(
        &mut AdamClock,
        &Opacity,
        &Temporal,
        &WarpedTime,
        Option<&TimeWindow>,
    )>,
) {
    let through = state.iteration.saturating_sub(1);
    let every = faded_geometry_read(&settings, every_gaussian.is_some());
    let (model, time) = (settings.opacity, sample.time);
    gaussians
        .par_iter_mut()
        .for_each(|(mut clock, opacity, temporal, warped, window)| {
            if clock.0 < through
                && (every || drawable(opacity_at(model, opacity, temporal, warped, window, time)))
            {
                clock.0 |= BEHIND;
            }
        });
}

/// Under `train.deferred_adam`, before the deformation: brings group `P` of every Gaussian
/// the view can draw up to date through the previous iteration (those
/// [`mark_drawable_behind`] marked), by the momentum steps of dense Adam it missed while it
/// got no gradient. Its gradient is then taken at the parameters dense Adam would have given
/// it, so that training follows dense Adam's trajectory up to rounding.
pub fn catch_up_drawable<P: ParamGroup>(
    settings: Res<Settings>,
    state: Res<TrainState>,
    mut sums: Local<DeferredSums>,
    mut params: Query<(&mut P, &mut Adam<P>, &AdamClock)>,
) {
    let through = state.iteration.saturating_sub(1);
    if !P::DEFERRED || through == 0 {
        return;
    }
    sums_through::<P>(&mut sums, &settings, through);
    let sums = &*sums;
    let floats = P::FLOATS;
    let active = P::active_values(state.sh_degree);
    params
        .contiguous_par_iter_mut()
        .expect("parameter components are stored in tables, so the query is dense")
        .for_each(|(mut values, mut moments, clocks)| {
            let values: &mut [f32] = bytemuck::cast_slice_mut(&mut values[..]);
            let moments: &mut [StoredMoments] = bytemuck::cast_slice_mut(&mut moments[..]);
            let mut coefficients = [0.0; MAX_GROUP_FLOATS];
            let coefficients = &mut coefficients[..active];
            let mut row =
                |values: &mut [f32], moments: &mut [StoredMoments], i: usize, last: u32| {
                    let x = &mut values[i * floats..(i + 1) * floats];
                    let mv = &mut moments[i * floats..(i + 1) * floats];
                    catch_up(x, mv, sums, last, through, coefficients);
                };
            // The rows lie scattered over the table: each is prefetched a few rows ahead of
            // its update, as in `adam_step`.
            let mut ahead = RowsAhead::default();
            for (i, clock) in clocks.iter().enumerate() {
                if clock.0 & BEHIND == 0 {
                    continue;
                }
                prefetch(&values[i * floats..(i + 1) * floats]);
                prefetch(&moments[i * floats..(i + 1) * floats]);
                if let Some((i, last)) = ahead.push(i, clock.0 & !BEHIND) {
                    row(values, moments, i, last);
                }
            }
            while let Some((i, last)) = ahead.pop() {
                row(values, moments, i, last);
            }
        });
}

/// After [`catch_up_drawable`]: the Gaussians it brought up to date are so through the
/// previous iteration (and their marks are cleared).
pub fn clock_drawable(state: Res<TrainState>, mut clocks: Query<&mut AdamClock>) {
    let through = state.iteration.saturating_sub(1);
    clocks.par_iter_mut().for_each(|mut clock| {
        if clock.0 & BEHIND != 0 {
            clock.0 = through;
        }
    });
}

/// The systems that bring the Gaussians a view can draw up to date under
/// `train.deferred_adam`, for the Deform stage before [`crate::systems::deform::deform`]:
/// [`mark_drawable_behind`], [`catch_up_drawable`] for every parameter group, then
/// [`clock_drawable`].
pub fn catch_up_systems() -> ScheduleConfigs<ScheduleSystem> {
    macro_rules! catch_ups {
        ($($group:ty,)*) => {
            ($(catch_up_drawable::<$group>,)*)
        };
    }
    (
        mark_drawable_behind,
        each_param!(catch_ups),
        catch_up_drawable::<MotionWeights>.run_if(resource_exists::<SharedMotion>),
        clock_drawable,
    )
        .chain()
        .run_if(deferring)
}

/// The most values a parameter group holds per Gaussian (the higher SH bands: 45).
const MAX_GROUP_FLOATS: usize = 3 * (SH_COEFFS - 1);

/// Marks how far [`adam_step`] brought each Gaussian under `train.deferred_adam`: this
/// iteration for those that received a gradient, and for all at a catch-up ([`catches_up`]).
pub fn advance_adam_clocks(
    settings: Res<Settings>,
    state: Res<TrainState>,
    buffers: Option<Res<SplatBuffers>>,
    mut clocks: Query<(&mut AdamClock, Option<&SplatSlot>)>,
) {
    let iteration = state.iteration;
    let reached = buffers.as_deref().map(|b| b.gradient_reached.as_slice());
    let all = catches_up(&settings, iteration) || reached.is_none();
    clocks.par_iter_mut().for_each(|(mut clock, slot)| {
        let seen = || {
            slot.and_then(|s| reached?.get(s.0 as usize).copied())
                .unwrap_or(true)
        };
        if all || seen() {
            clock.0 = iteration;
        }
    });
}

/// Run condition: `train.deferred_adam` is on.
pub fn deferring(settings: Res<Settings>) -> bool {
    settings.train.deferred_adam
}

crate::raster::simd_kernel! {
    /// Adam on consecutive Gaussians of one group: `values`, `grads` and `moments` hold
    /// `floats` values per Gaussian (the moments as stored pairs); the first `rates.len()`
    /// values of each Gaussian are stepped, each with its learning rate, and their moments
    /// stored rounded with `seed`'s bits.
    ///
    /// Compiled for AVX2 and AVX-512 as well, and run at the level the rasterizer's loops use
    /// ([`crate::raster::simd_level`]): the baseline x86-64 target has four lanes and no 32-bit
    /// vector multiplication for the rounding's hash (at 1 M Gaussians Adam took 44–50 ms
    /// without it, 27–30 with AVX2). The arithmetic is the same at every level (nothing is
    /// contracted into fused multiply-adds), so all give the same results bit for bit.
    fn adam_values(
        values: &mut [f32],
        grads: &[f32],
        moments: &mut [StoredMoments],
        floats: usize,
        rates: &[f32],
        bias: BiasCorrection,
        seed: u32,
    ) {
        // The groups' widths as constants, each with a block of 8 Gaussians, so that the update
        // runs over whole blocks of values as vectors (the rates repeat with the block).
        macro_rules! fixed_widths {
            ($($width:literal $block:literal)*) => {
                match (floats, rates.len()) {
                    $(($width, $width) => {
                        return adam_fixed::<$width, $block>(values, grads, moments, rates, bias, seed)
                    })*
                    _ => {}
                }
            };
        }
        fixed_widths!(1 8 3 24 6 48 8 64 16 128 28 224 45 360);
        // Any other width, or a group whose last values are not stepped.
        let gaussians = values
            .chunks_exact_mut(floats)
            .zip(grads.chunks_exact(floats))
            .zip(moments.chunks_exact_mut(floats));
        for ((x, g), mv) in gaussians {
            for (((x, g), mv), lr) in x.iter_mut().zip(g).zip(mv).zip(rates) {
                adam_update_stored(x, *g, mv, *lr, bias, seed);
            }
        }
    }
}

/// [`adam_values`] for groups of `WIDTH` values, all stepped, in blocks of `BLOCK` values
/// (8 Gaussians) and then the Gaussians left over (all of them when one row is stepped, as the
/// sparse paths of [`adam_step`] do).
#[inline(always)]
fn adam_fixed<const WIDTH: usize, const BLOCK: usize>(
    values: &mut [f32],
    grads: &[f32],
    moments: &mut [StoredMoments],
    rates: &[f32],
    bias: BiasCorrection,
    seed: u32,
) {
    debug_assert_eq!(BLOCK % WIDTH, 0);
    let rates: &[f32; WIDTH] = rates.try_into().expect("one rate per value");
    let (value_blocks, values_left) = values.as_chunks_mut::<BLOCK>();
    let (grad_blocks, grads_left) = grads.as_chunks::<BLOCK>();
    let (moment_blocks, moments_left) = moments.as_chunks_mut::<BLOCK>();
    if !value_blocks.is_empty() {
        let block_rates: [f32; BLOCK] = std::array::from_fn(|k| rates[k % WIDTH]);
        let blocks = value_blocks.iter_mut().zip(grad_blocks).zip(moment_blocks);
        for ((x, g), mv) in blocks {
            for k in 0..BLOCK {
                adam_update_stored(&mut x[k], g[k], &mut mv[k], block_rates[k], bias, seed);
            }
        }
    }
    let left = values_left
        .as_chunks_mut::<WIDTH>()
        .0
        .iter_mut()
        .zip(grads_left.as_chunks::<WIDTH>().0)
        .zip(moments_left.as_chunks_mut::<WIDTH>().0);
    for ((x, g), mv) in left {
        for j in 0..WIDTH {
            adam_update_stored(&mut x[j], g[j], &mut mv[j], rates[j], bias, seed);
        }
    }
}

/// One Adam step on the exposure correction of the camera the loss trained on (see
/// [`CameraExposures`]), then re-centres the corrections over the training cameras.
///
/// Scaling every camera's gain by k while dividing the Gaussians' colours by k (or shifting
/// offsets against colours) leaves the loss unchanged. Centring pins that freedom: the model
/// keeps the colours of an average training camera, which is what a held-out camera, drawn
/// without a correction, is assumed to see.
pub fn adam_exposure(settings: Res<Settings>, exposures: Option<ResMut<CameraExposures>>) {
    let Some(mut exposures) = exposures else {
        return;
    };
    let Some((index, grad)) = exposures.grad.take() else {
        return;
    };
    let lr = settings.train.lr.exposure;
    let camera = &mut exposures.cameras[index];
    camera.steps += 1;
    let bias = BiasCorrection::after(camera.steps.min(i32::MAX as u32) as i32);
    let mut values = camera.exposure.values();
    for (i, g) in grad.values().into_iter().enumerate() {
        adam_update(
            &mut values[i],
            g,
            &mut camera.m[i],
            &mut camera.v[i],
            lr,
            bias,
        );
    }
    camera.exposure = Exposure::from_values(values);

    let trained = exposures.cameras.iter().filter(|c| c.trained);
    let count = trained.clone().count().max(1) as f32;
    let mean: [f32; 6] = trained.fold([0.0; 6], |sum, c| {
        let v = c.exposure.values();
        std::array::from_fn(|i| sum[i] + v[i] / count)
    });
    for camera in exposures.cameras.iter_mut().filter(|c| c.trained) {
        let v = camera.exposure.values();
        camera.exposure = Exposure::from_values(std::array::from_fn(|i| v[i] - mean[i]));
    }
}

/// One Adam step on the shared motion bases ([`SharedMotion`], `model.shared_motion`), with
/// the bias correction of the global step as the Gaussians' groups (the bases get a gradient
/// every iteration a Gaussian with weights is seen) and [`motion_bases_lr`].
pub fn adam_shared_motion(
    settings: Res<Settings>,
    state: Res<TrainState>,
    mut shared: ResMut<SharedMotion>,
) {
    let iteration = state.iteration;
    let lr = motion_bases_lr(
        &settings.train.rates_at(iteration),
        iteration,
        settings.train.iterations,
        settings.extent,
    );
    let bias = BiasCorrection::after(iteration.max(1) as i32);
    let shared = &mut *shared;
    let values: &mut [f32] = bytemuck::cast_slice_mut(&mut shared.bases.values);
    let grads: &[f32] = bytemuck::cast_slice(&shared.grad);
    let m: &mut [f32] = bytemuck::cast_slice_mut(&mut shared.m);
    let v: &mut [f32] = bytemuck::cast_slice_mut(&mut shared.v);
    for (((x, g), m), v) in values.iter_mut().zip(grads).zip(m).zip(v) {
        adam_update(x, *g, m, v, lr, bias);
    }
}

/// The Adam systems of every parameter group ([`crate::components::param_groups!`]), the
/// fused pass for Gaussians without gradient components ([`crate::systems::fused`]), and with
/// shared motion ([`SharedMotion`]) the Adam systems of the Gaussians' weights and of the
/// bases.
pub fn adam_systems() -> ScheduleConfigs<ScheduleSystem> {
    macro_rules! adam_steps {
        ($($group:ty,)*) => {
            ($(adam_step::<$group>,)*)
        };
    }
    (
        each_param!(adam_steps),
        crate::systems::fused::backward_and_step,
        (adam_step::<MotionWeights>, adam_shared_motion)
            .chain()
            .run_if(resource_exists::<SharedMotion>),
        advance_adam_clocks.run_if(deferring),
    )
        .chain()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::adam::store_moments_nearest;

    /// The chunked update steps each Gaussian's active values exactly as the scalar
    /// [`adam_update_stored`] does (bit for bit), whatever the group's width, and leaves the values
    /// past the active ones (and their moments) untouched. On a CPU with AVX2 this compares the
    /// AVX2 build of the update with the baseline build of the scalar one.
    #[test]
    fn adam_values_equal_scalar_updates() {
        let bias = BiasCorrection::after(7);
        for (floats, active) in [
            (1, 1),
            (3, 3),
            (6, 6),
            (5, 5),
            (8, 8),
            (16, 16),
            (28, 28),
            (45, 45),
            (45, 24),
            (45, 0),
        ] {
            let gaussians = 37;
            let value = |i: usize| ((i * 7919) % 1000) as f32 / 250.0 - 2.0;
            let mut x: Vec<f32> = (0..gaussians * floats).map(value).collect();
            let g: Vec<f32> = (0..gaussians * floats)
                .map(|i| 1e-3 * value(i + 13))
                .collect();
            let mut mv: Vec<StoredMoments> = (0..gaussians * floats)
                .map(|i| store_moments_nearest([1e-3 * value(i + 29), 1e-4 * value(i + 31).abs()]))
                .collect();
            let rates: Vec<f32> = (0..floats).map(|j| 1e-3 * (j + 1) as f32).collect();

            let (mut x_ref, mut mv_ref) = (x.clone(), mv.clone());
            for i in 0..gaussians {
                for j in 0..active {
                    let k = floats * i + j;
                    adam_update_stored(&mut x_ref[k], g[k], &mut mv_ref[k], rates[j], bias, 11);
                }
            }
            adam_values(&mut x, &g, &mut mv, floats, &rates[..active], bias, 11);

            let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&x),
                bits(&x_ref),
                "values, {floats} floats, {active} active"
            );
            assert_eq!(mv, mv_ref, "moments, {floats} floats, {active} active");
        }
    }
}
