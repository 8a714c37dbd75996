//! The training stages on the GPU-resident pipeline ([`GpuTraining`]): when that resource is
//! present these systems run in place of the CPU deformation, splatting, backward, guard, Adam
//! and statistics systems (which are skipped by [`on_cpu`]), in the same [`super::TrainSet`]s.
//!
//! The ECS components are the truth only after [`resident_sync`]: it runs before densification and
//! opacity resets (and [`sync_world`] before checkpoints, export and evaluation) and marks the
//! GPU copy stale, so the next [`resident_forward`] uploads the components again.

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
    let count = slots.iter(world).len();
    let gpu = world.resource::<GpuTraining>();
    if !gpu.is_dirty() && count == gpu.len() {
        return Ok(());
    }
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
    Ok(())
}

/// Copies group `P`'s values and moments of every Gaussian into their slots of `state`.
fn gather<P: Param>(world: &mut World, state: &mut ResidentState, count: usize) {
    for (value, adam, slot) in world.query::<(&P, &Adam<P>, &SplatSlot)>().iter(world) {
        let range = group_range::<P>(count, slot.0 as usize);
        state.params[range.clone()].copy_from_slice(value.values());
        state.m[range.clone()].copy_from_slice(adam.m.values());
        state.v[range].copy_from_slice(adam.v.values());
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
        settings.train.background,
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

/// One Adam step of every parameter group on the GPU.
pub fn resident_adam(
    settings: Res<Settings>,
    state: Res<TrainState>,
    mut gpu: ResMut<GpuTraining>,
    mut rates: Local<[Vec<f32>; SECTIONS]>,
) {
    let lr = &settings.train.lr;
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
pub fn resident_stats(settings: Res<Settings>, mut gpu: ResMut<GpuTraining>) {
    gpu.accumulate_stats(&StatsConfig::from_settings(&settings));
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
/// marks the GPU copy stale.
pub fn resident_sync(world: &mut World, mut scratch: Local<SyncScratch>) -> Result {
    let SyncScratch {
        state,
        grads,
        deformed,
    } = &mut *scratch;
    {
        let mut gpu = world.resource_mut::<GpuTraining>();
        if gpu.is_dirty() {
            // Nothing ran on the GPU since the components were last written.
            return Ok(());
        }
        gpu.read(state)?;
        gpu.read_gradient_values(grads)?;
        gpu.read_deformed(deformed)?;
    }
    macro_rules! scatter_every_group {
        ($($group:ty,)*) => {
            $(scatter::<$group>(world, state, grads);)*
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

/// Copies group `P`'s values, moments and gradient of every Gaussian that has the group out of
/// its slot of `state` and `grads`.
fn scatter<P: Param>(world: &mut World, state: &ResidentState, grads: &[f32]) {
    let count = state.len();
    for (mut value, mut adam, mut grad, slot) in world
        .query::<(&mut P, &mut Adam<P>, &mut Grad<P>, &SplatSlot)>()
        .iter_mut(world)
    {
        let range = group_range::<P>(count, slot.0 as usize);
        let get = |values: &[f32]| -> P {
            bytemuck::pod_read_unaligned(bytemuck::cast_slice(&values[range.clone()]))
        };
        *value = get(&state.params);
        *adam = Adam {
            m: get(&state.m),
            v: get(&state.v),
        };
        *grad = Grad(get(grads));
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
