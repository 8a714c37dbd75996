//! The training stages on the GPU-resident pipeline ([`GpuTraining`]), installed by
//! [`GpuResidentBackend`]: when that resource is present these systems run in place of the
//! CPU deformation, splatting, backward, guard, Adam and statistics systems (which are skipped
//! by [`on_cpu`]), in the same [`super::TrainSet`]s.
//!
//! The ECS components are the truth only after [`resident_sync`]: it runs before densification and
//! opacity resets (and [`sync_world`] before checkpoints, export and evaluation) and marks the
//! GPU copy stale, so the next [`resident_upload`] uploads the components again.
//!
//! Systems of your own see the same components as on the CPU backend, or an error says what to
//! add: a change of a parameter, its Adam moments or the population while the GPU holds them
//! is refused (run [`resident_sync`] right before such a system), and so is a change of a
//! [`Grad`] between Backward and Adam unless the [`HostGradients`] resource asks for the
//! gradients to visit the components ([`resident_gradients_out`], [`resident_gradients_in`]).
//! What the GPU keeps to itself between syncs cannot be *read* from the components either:
//! sync before reading parameters, and insert [`HostGradients`] to read gradients.

use bevy_ecs::change_detection::Tick;
use bevy_ecs::prelude::*;
use bevy_ecs::system::RunSystemOnce;

use crate::components::{
    Adam, Deformed, Grad, GradAccum, PARAM_GROUPS, Param, SplatSlot, WarpedTime, each_param,
};
use crate::gpu::{DeformSettings, GpuTraining, ResidentState, StatsConfig};
use crate::layout::{PARAM_FLOATS, SECTIONS, WIDTHS, group_range, offset_in_section};
use crate::resources::{
    Fault, LossImage, NumericFault, Settings, SplatBuffers, TrainState, ViewSample,
};
use crate::systems::adam::{ParamGroup, position_lr};

/// Opt-in for the GPU-resident backend: the gradients are copied into the [`Grad`] components
/// at the end of [`super::TrainSet::Backward`] and back to the GPU at the start of
/// [`super::TrainSet::Adam`], so that systems between the two stages read and edit them as on
/// the CPU backend (`examples/custom_system.rs`). It costs one readback and one upload of every
/// gradient per iteration; the CPU backend ignores it. Without it, the gradients stay on the
/// GPU and an edit of a [`Grad`] between the two stages is refused with an error.
#[derive(Resource, Default, Debug, Clone, Copy)]
pub struct HostGradients;

/// When the resident systems last handed the components to the GPU and the gradients to the
/// components: a component changed after that was edited by a system the GPU did not see.
#[derive(Resource, Default, Debug, Clone, Copy)]
struct ResidentTicks {
    uploaded: Tick,
    backward: Tick,
}

/// The GPU-resident backend: runs when the world holds a [`GpuTraining`] resource.
pub struct GpuResidentBackend;

impl super::BackendPlugin for GpuResidentBackend {
    fn add_render_systems(&self, schedule: &mut Schedule) {
        schedule.add_systems(
            (resident_upload, resident_forward)
                .chain()
                .run_if(on_gpu)
                .in_set(super::TrainSet::Splat),
        );
    }

    fn add_backward_systems(&self, schedule: &mut Schedule) {
        schedule.add_systems(
            (resident_backward, resident_gradients_out)
                .chain()
                .run_if(on_gpu)
                .in_set(super::TrainSet::Backward),
        );
    }

    fn add_update_systems(&self, schedule: &mut Schedule) {
        use super::densify::{
            densify_and_prune, densify_step, densifying, opacity_reset_step, reset_opacity,
        };
        schedule.add_systems(
            (resident_gradients_in, resident_adam)
                .chain()
                .run_if(on_gpu)
                .in_set(super::TrainSet::Adam),
        );
        schedule.add_systems(
            (
                resident_stats.run_if(densifying),
                // The components are the truth again before they change.
                resident_sync.run_if(densify_step.or_else(opacity_reset_step)),
            )
                .chain()
                .run_if(on_gpu)
                .in_set(super::TrainSet::Densify)
                .before(densify_and_prune)
                .before(reset_opacity),
        );
    }
}

/// Run condition: the CPU stages run (no [`GpuTraining`] resource).
pub fn on_cpu(gpu: Option<Res<GpuTraining>>) -> bool {
    gpu.is_none()
}

/// Run condition: the GPU-resident stages run.
pub fn on_gpu(gpu: Option<Res<GpuTraining>>) -> bool {
    gpu.is_some()
}

/// When the GPU copy is stale (or the population changed), assigns each Gaussian its
/// [`SplatSlot`] and uploads every parameter group, its Adam moments and the densification
/// statistics in the resident layout. Groups a Gaussian lacks (the higher SH bands of a
/// degree-0 model) are uploaded as zeros.
pub fn resident_upload(
    world: &mut World,
    slots: &mut QueryState<&mut SplatSlot>,
    mut state: Local<ResidentState>,
) -> Result {
    let state = &mut *state;
    if !world.resource::<GpuTraining>().is_dirty() {
        // The GPU holds the parameters: the components are stale and not uploaded again.
        return refuse_parameter_edits(world);
    }
    let count = slots.iter(world).len();
    for (slot, mut splat_slot) in slots.iter_mut(world).enumerate() {
        splat_slot.0 = slot as u32;
    }
    state.clear();
    for values in [&mut state.params, &mut state.m, &mut state.v] {
        values.resize(count * PARAM_FLOATS, 0.0);
    }
    state.accum.resize(count, GradAccum::default());
    macro_rules! gather_every_group {
        ($($group:ty,)*) => {
            $(gather::<$group>(world, state, count);)*
        };
    }
    each_param!(gather_every_group);
    for (accum, slot) in world.query::<(&GradAccum, &SplatSlot)>().iter(world) {
        state.accum[slot.0 as usize] = *accum;
    }
    world.resource_mut::<GpuTraining>().upload(&state)?;
    let now = world.change_tick();
    world
        .get_resource_or_insert_with(ResidentTicks::default)
        .uploaded = now;
    Ok(())
}

/// Fails when a system spawned or despawned Gaussians, or changed a parameter or its Adam
/// moments, after the last upload while the GPU holds the parameters: the edit would be lost
/// (overwritten by the next [`resident_sync`]), or, for a spawn, the stale components uploaded.
fn refuse_parameter_edits(world: &mut World) -> Result {
    let uploaded = world
        .get_resource_or_insert_with(ResidentTicks::default)
        .uploaded;
    let resident = world.resource::<GpuTraining>().len();
    let count = world.query::<&SplatSlot>().iter(world).len();
    if count != resident {
        return Err(stale_edit(format!(
            "the number of Gaussians changed from {resident} to {count} outside densification"
        )));
    }
    macro_rules! every_group_edits {
        ($($group:ty,)*) => {
            $(
                let edited = changed_since::<$group>(world, uploaded)
                    + changed_since::<Adam<$group>>(world, uploaded);
                if edited > 0 {
                    return Err(stale_edit(format!(
                        "a system changed the {} or its Adam moments of {edited} Gaussians",
                        <$group as Param>::NAME
                    )));
                }
            )*
        };
    }
    each_param!(every_group_edits);
    Ok(())
}

fn stale_edit(what: String) -> BevyError {
    format!(
        "{what} while the GPU-resident backend held the parameters, so the edit would be lost: \
         run `tadgs::systems::resident::resident_sync` right before such a system (it brings \
         the components up to date and has the GPU take them back; a no-op on the CPU backend)"
    )
    .into()
}

/// How many `C` components changed (or were added) after `tick`.
fn changed_since<C: Component>(world: &mut World, tick: Tick) -> usize {
    let now = world.change_tick();
    world
        .query::<Ref<C>>()
        .iter(world)
        .filter(|c| c.last_changed().is_newer_than(tick, now))
        .count()
}

/// Copies group `P`'s values and moments of every Gaussian into their slots of `state`.
fn gather<P: Param>(world: &mut World, state: &mut ResidentState, count: usize) {
    for (value, adam, slot) in world.query::<(&P, &Adam<P>, &SplatSlot)>().iter(world) {
        let range = group_range::<P>(count, slot.0 as usize);
        state.params[range.clone()].copy_from_slice(value.values());
        state.m[range.clone()].copy_from_slice(adam.m().values());
        state.v[range].copy_from_slice(adam.v().values());
    }
}

/// Deforms, projects, bins and blends the sampled view on the GPU into
/// [`SplatBuffers::render`] (after [`resident_upload`]).
pub fn resident_forward(
    settings: Res<Settings>,
    state: Res<TrainState>,
    sample: Res<ViewSample>,
    mut buffers: ResMut<SplatBuffers>,
    mut gpu: ResMut<GpuTraining>,
    gaussians: Query<(&WarpedTime, &SplatSlot)>,
    mut warped: Local<Vec<WarpedTime>>,
) -> Result {
    warped.clear();
    warped.resize(gaussians.iter().len(), WarpedTime::default());
    for (time, slot) in gaussians.iter() {
        warped[slot.0 as usize] = *time;
    }
    let deform = DeformSettings::new(&settings, &state);
    gpu.forward(
        &warped,
        &sample.camera,
        &deform,
        sample.background,
        &mut buffers.render,
    )?;
    Ok(())
}

/// Back-propagates [`LossImage::d_color`] on the GPU into the resident gradients and records a
/// [`NumericFault`] when the loss or a gradient is not finite (the guard of the CPU schedule).
pub fn resident_backward(
    state: Res<TrainState>,
    loss: Res<LossImage>,
    mut fault: ResMut<NumericFault>,
    mut gpu: ResMut<GpuTraining>,
) -> Result {
    let found = gpu.backward(&loss.d_color)?;
    if fault.0.is_some() {
        return Ok(());
    }
    let found = if !state.loss.total.is_finite() {
        Some(("loss", None))
    } else {
        found.map(|f| (f.group, Some(f.gaussian)))
    };
    if let Some((group, gaussian)) = found {
        fault.0 = Some(Fault {
            iteration: state.iteration,
            group,
            gaussian,
        });
    }
    Ok(())
}

/// Ends the GPU-resident Backward stage: with [`HostGradients`], reads this iteration's
/// gradients into the [`Grad`] components; either way notes the tick, so that
/// [`resident_gradients_in`] can tell the edits of later systems.
pub fn resident_gradients_out(world: &mut World, mut grads: Local<Vec<f32>>) -> Result {
    if world.contains_resource::<HostGradients>() {
        world
            .resource_mut::<GpuTraining>()
            .read_gradient_values(&mut grads)?;
        let count = world.resource::<GpuTraining>().len();
        macro_rules! scatter_every_gradient {
            ($($group:ty,)*) => {
                $(scatter_gradient::<$group>(world, &grads, count);)*
            };
        }
        each_param!(scatter_every_gradient);
    }
    let now = world.change_tick();
    world
        .get_resource_or_insert_with(ResidentTicks::default)
        .backward = now;
    Ok(())
}

/// Starts the GPU-resident Adam stage: with [`HostGradients`], writes the [`Grad`] components
/// (as the systems since Backward left them) back to the GPU; without, fails if a system
/// changed one, since the GPU would step with the gradients it computed.
pub fn resident_gradients_in(world: &mut World, mut grads: Local<Vec<f32>>) -> Result {
    if world.contains_resource::<HostGradients>() {
        let count = world.resource::<GpuTraining>().len();
        grads.clear();
        grads.resize(count * PARAM_FLOATS, 0.0);
        macro_rules! gather_every_gradient {
            ($($group:ty,)*) => {
                $(gather_gradient::<$group>(world, &mut grads, count);)*
            };
        }
        each_param!(gather_every_gradient);
        world
            .resource_mut::<GpuTraining>()
            .write_gradient_values(&grads);
        return Ok(());
    }
    let backward = world
        .get_resource_or_insert_with(ResidentTicks::default)
        .backward;
    macro_rules! every_gradient_edit {
        ($($group:ty,)*) => {
            $(
                let edited = changed_since::<Grad<$group>>(world, backward);
                if edited > 0 {
                    return Err(format!(
                        "a system changed Grad<{}> of {edited} Gaussians between \
                         TrainSet::Backward and TrainSet::Adam, but the GPU-resident backend \
                         keeps the gradients on the GPU, so the edit would be lost: insert the \
                         `tadgs::systems::resident::HostGradients` resource to have them \
                         copied to the components and back (one readback and one upload per \
                         iteration)",
                        <$group as Param>::NAME
                    )
                    .into());
                }
            )*
        };
    }
    each_param!(every_gradient_edit);
    Ok(())
}

/// Copies group `P`'s gradient of every Gaussian that has the group out of its slot of `grads`.
fn scatter_gradient<P: Param>(world: &mut World, grads: &[f32], count: usize) {
    for (mut grad, slot) in world.query::<(&mut Grad<P>, &SplatSlot)>().iter_mut(world) {
        let range = group_range::<P>(count, slot.0 as usize);
        *grad = Grad(bytemuck::pod_read_unaligned(bytemuck::cast_slice(
            &grads[range],
        )));
    }
}

/// Copies group `P`'s gradient of every Gaussian that has the group into its slot of `grads`.
fn gather_gradient<P: Param>(world: &mut World, grads: &mut [f32], count: usize) {
    for (grad, slot) in world.query::<(&Grad<P>, &SplatSlot)>().iter(world) {
        let range = group_range::<P>(count, slot.0 as usize);
        grads[range].copy_from_slice(grad.0.values());
    }
}

/// One Adam step of every parameter group on the GPU.
pub fn resident_adam(
    settings: Res<Settings>,
    state: Res<TrainState>,
    mut gpu: ResMut<GpuTraining>,
    mut rates: Local<[Vec<f32>; SECTIONS]>,
) {
    let lr = &settings.train.rates_at(state.iteration);
    let plr = position_lr(
        lr,
        state.iteration,
        settings.train.iterations,
        settings.extent,
    );
    for (section, width) in rates.iter_mut().zip(WIDTHS) {
        section.resize(width, 0.0);
    }
    macro_rules! every_group_rates {
        ($($group:ty,)*) => {
            $(put_rates::<$group>(&mut rates, <$group>::learning_rates(lr, plr).values());)*
        };
    }
    each_param!(every_group_rates);
    gpu.adam(std::array::from_fn(|k| &rates[k][..]), state.iteration);
}

/// Places group `P`'s per-value learning rates in its section's rates.
fn put_rates<P: Param>(rates: &mut [Vec<f32>; SECTIONS], values: &[f32]) {
    let offset = offset_in_section(P::INDEX);
    rates[PARAM_GROUPS[P::INDEX].section][offset..offset + P::FLOATS].copy_from_slice(values);
}

/// Adds this iteration's view to the resident densification statistics.
pub fn resident_stats(
    settings: Res<Settings>,
    sample: Res<ViewSample>,
    mut gpu: ResMut<GpuTraining>,
) {
    gpu.accumulate_stats(&StatsConfig::from_settings(&settings, sample.time));
}

/// Host scratch of [`resident_sync`].
#[derive(Default)]
pub struct SyncScratch {
    state: ResidentState,
    grads: Vec<f32>,
    deformed: Vec<Deformed>,
}

/// Reads the parameters, Adam moments and statistics back into the components (by
/// [`SplatSlot`]), and the last iteration's gradients and deformed Gaussians into
/// [`Grad`] and [`Deformed`], which the resident iteration itself never writes: after a sync,
/// systems and tools that read them see what the CPU schedule would have left there. Then
/// marks the GPU copy stale. A no-op on the CPU backend (no [`GpuTraining`]) and when the
/// components are already the truth.
pub fn resident_sync(world: &mut World, mut scratch: Local<SyncScratch>) -> Result {
    let SyncScratch {
        state,
        grads,
        deformed,
    } = &mut *scratch;
    {
        match world.get_resource::<GpuTraining>() {
            // The CPU backend: the components are the truth.
            None => return Ok(()),
            // Nothing ran on the GPU since the components were last written.
            Some(gpu) if gpu.is_dirty() => return Ok(()),
            Some(_) => {}
        }
        refuse_parameter_edits(world)?;
        let mut gpu = world.resource_mut::<GpuTraining>();
        gpu.read(state)?;
        gpu.read_gradient_values(grads)?;
        gpu.read_deformed(deformed)?;
    }
    macro_rules! scatter_every_group {
        ($($group:ty,)*) => {
            $(
                scatter::<$group>(world, state);
                scatter_gradient::<$group>(world, grads, state.len());
            )*
        };
    }
    each_param!(scatter_every_group);
    for (mut deformed_out, mut accum, slot) in world
        .query::<(&mut Deformed, &mut GradAccum, &SplatSlot)>()
        .iter_mut(world)
    {
        let s = slot.0 as usize;
        *deformed_out = deformed[s];
        *accum = state.accum[s];
    }
    world.resource_mut::<GpuTraining>().mark_dirty();
    Ok(())
}

/// Copies group `P`'s values and moments of every Gaussian that has the group out of its slot
/// of `state`.
fn scatter<P: Param>(world: &mut World, state: &ResidentState) {
    let count = state.len();
    for (mut value, mut adam, slot) in world
        .query::<(&mut P, &mut Adam<P>, &SplatSlot)>()
        .iter_mut(world)
    {
        let range = group_range::<P>(count, slot.0 as usize);
        let get = |values: &[f32]| -> P {
            bytemuck::pod_read_unaligned(bytemuck::cast_slice(&values[range.clone()]))
        };
        *value = get(&state.params);
        *adam = Adam::new(&get(&state.m), &get(&state.v));
    }
}

/// Runs [`resident_sync`] on `world` when it trains on the GPU-resident pipeline (a no-op otherwise):
/// call it before reading parameters, moments or statistics from the components.
pub fn sync_world(world: &mut World) -> Result {
    if world.contains_resource::<GpuTraining>() {
        let result: std::result::Result<(), _> = world.run_system_once(resident_sync);
        result.map_err(|e| std::io::Error::other(e.to_string()))?;
    }
    Ok(())
}
