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
    Adam, AdamRefs, Color, ColorRest, Deformed, Fourier, Grad, GradAccum, Opacity, Param, ParamRefs,
    Position, Rotation, Scale, ShCoefficients, SplatSlot, Temporal, WarpedTime, sh_coefficients,
    split_sh,
};
use crate::gpu::{DeformSettings, GpuTraining, ParamGradients, ResidentState, StatsConfig};
use crate::resources::{
    Fault, LossImage, NumericFault, Settings, SplatBuffers, TrainState, ViewSample,
};
use crate::systems::adam::{ParamGroup, position_lr};
use crate::systems::backward::ParamGrads;

/// The parameters and Adam moments of one Gaussian, writable.
pub type ResidentMuts<'a> = (
    (
        &'a mut Position,
        &'a mut Fourier,
        &'a mut Temporal,
        &'a mut Opacity,
        &'a mut Rotation,
        &'a mut Scale,
        &'a mut Color,
        Option<&'a mut ColorRest>,
    ),
    (
        &'a mut Adam<Position>,
        &'a mut Adam<Fourier>,
        &'a mut Adam<Temporal>,
        &'a mut Adam<Opacity>,
        &'a mut Adam<Rotation>,
        &'a mut Adam<Scale>,
        &'a mut Adam<Color>,
        Option<&'a mut Adam<ColorRest>>,
    ),
);

/// Run condition: the CPU stages run (no [`GpuTraining`] resource).
pub fn on_cpu(gpu: Option<Res<GpuTraining>>) -> bool {
    gpu.is_none()
}

/// Run condition: the GPU-resident stages run.
pub fn on_gpu(gpu: Option<Res<GpuTraining>>) -> bool {
    gpu.is_some()
}

/// Host scratch of [`resident_forward`].
#[derive(Default)]
pub struct ForwardScratch {
    sections: [[Vec<f32>; 7]; 3],
    state: ResidentState,
    warped: Vec<WarpedTime>,
}

/// Uploads the components when the GPU copy is stale (assigning each Gaussian its
/// [`SplatSlot`]), then deforms, projects, bins and blends the sampled view on the GPU into
/// [`SplatBuffers::render`].
#[allow(clippy::too_many_arguments)]
pub fn resident_forward(
    settings: Res<Settings>,
    state: Res<TrainState>,
    sample: Res<ViewSample>,
    mut buffers: ResMut<SplatBuffers>,
    mut gpu: ResMut<GpuTraining>,
    mut gaussians: Query<(ParamRefs, AdamRefs, &GradAccum, &WarpedTime, &mut SplatSlot)>,
    mut scratch: Local<ForwardScratch>,
) -> Result {
    let scratch = &mut *scratch;
    let count = gaussians.iter().len();
    if gpu.is_dirty() || count != gpu.len() {
        for group in scratch.sections.iter_mut().flatten() {
            group.clear();
        }
        scratch.state.clear();
        for (slot, (params, adam, accum, _, mut splat_slot)) in gaussians.iter_mut().enumerate() {
            splat_slot.0 = slot as u32;
            let (p0, p1, p2, p3, p4, p5, p6, p7) = params;
            let (a0, a1, a2, a3, a4, a5, a6, a7) = adam;
            let (no_rest, no_moments) = (ColorRest::default(), Adam::<ColorRest>::default());
            let (p7, a7) = (p7.unwrap_or(&no_rest), a7.unwrap_or(&no_moments));
            // The GPU holds every SH band in one section: the higher bands (zero for a
            // Gaussian without them) follow the DC term.
            let values = [
                [p0.values(), a0.m.values(), a0.v.values()],
                [p1.values(), a1.m.values(), a1.v.values()],
                [p2.values(), a2.m.values(), a2.v.values()],
                [p3.values(), a3.m.values(), a3.v.values()],
                [p4.values(), a4.m.values(), a4.v.values()],
                [p5.values(), a5.m.values(), a5.v.values()],
                [p6.values(), a6.m.values(), a6.v.values()],
                [p7.values(), a7.m.values(), a7.v.values()],
            ];
            for (k, parts) in values.iter().enumerate() {
                for (kind, part) in parts.iter().enumerate() {
                    scratch.sections[kind][k.min(6)].extend_from_slice(part);
                }
            }
            scratch.state.accum.push(*accum);
        }
        let state = &mut scratch.state;
        for (kind, out) in [&mut state.params, &mut state.m, &mut state.v]
            .into_iter()
            .enumerate()
        {
            for section in &scratch.sections[kind] {
                out.extend_from_slice(section);
            }
        }
        gpu.upload(state)?;
    }
    scratch.warped.clear();
    scratch.warped.resize(count, WarpedTime::default());
    for (_, _, _, warped, slot) in gaussians.iter() {
        scratch.warped[slot.0 as usize] = *warped;
    }
    let deform = DeformSettings::new(&settings, &state);
    gpu.forward(
        &scratch.warped,
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
) {
    let lr = &settings.train.lr;
    let plr = position_lr(
        lr,
        state.iteration,
        settings.train.iterations,
        settings.extent,
    );
    let r0 = Position::learning_rates(lr, plr);
    let r1 = Fourier::learning_rates(lr, plr);
    let r2 = Temporal::learning_rates(lr, plr);
    let r3 = Opacity::learning_rates(lr, plr);
    let r4 = Rotation::learning_rates(lr, plr);
    let r5 = Scale::learning_rates(lr, plr);
    let r6 = sh_coefficients(
        &Color::learning_rates(lr, plr),
        Some(&ColorRest::learning_rates(lr, plr)),
    );
    gpu.adam(
        [
            r0.values(),
            r1.values(),
            r2.values(),
            r3.values(),
            r4.values(),
            r5.values(),
            r6.as_flattened(),
        ],
        state.iteration,
    );
}

/// Adds this iteration's view to the resident densification statistics.
pub fn resident_stats(settings: Res<Settings>, mut gpu: ResMut<GpuTraining>) {
    gpu.accumulate_stats(&StatsConfig::from_settings(&settings));
}

/// Host scratch of [`resident_sync`].
#[derive(Default)]
pub struct SyncScratch {
    state: ResidentState,
    grads: ParamGradients,
    deformed: Vec<Deformed>,
}

/// Reads the parameters, Adam moments and statistics back into the components (by
/// [`SplatSlot`]), and the last iteration's gradients and deformed Gaussians into
/// [`Grad`](crate::components::Grad) and [`Deformed`], which the resident iteration itself
/// never writes: after a sync, systems and tools that read them see what the CPU schedule
/// would have left there. Then marks the GPU copy stale.
pub fn resident_sync(
    mut gpu: ResMut<GpuTraining>,
    mut gaussians: Query<(
        ResidentMuts,
        ParamGrads,
        &mut Deformed,
        &mut GradAccum,
        &SplatSlot,
    )>,
    mut scratch: Local<SyncScratch>,
) -> Result {
    if gpu.is_dirty() {
        // Nothing ran on the GPU since the components were last written.
        return Ok(());
    }
    let SyncScratch {
        state,
        grads,
        deformed,
    } = &mut *scratch;
    gpu.read(state)?;
    gpu.read_gradients(grads)?;
    gpu.read_deformed(deformed)?;
    let n = state.len();
    fn put<P: Param>(
        state: &ResidentState,
        n: usize,
        k: usize,
        slot: usize,
        value: &mut P,
        adam: &mut Adam<P>,
    ) {
        *value = ResidentState::get(&state.params, n, k, slot);
        adam.m = ResidentState::get(&state.m, n, k, slot);
        adam.v = ResidentState::get(&state.v, n, k, slot);
    }
    for (
        ((p0, p1, p2, p3, p4, p5, p6, p7), (a0, a1, a2, a3, a4, a5, a6, a7)),
        (g0, g1, g2, g3, g4, g5, g6, g7),
        mut deformed_out,
        mut accum,
        slot,
    ) in gaussians.iter_mut()
    {
        let s = slot.0 as usize;
        *g0.into_inner() = grads.position[s];
        *g1.into_inner() = grads.fourier[s];
        *g2.into_inner() = grads.temporal[s];
        *g3.into_inner() = grads.opacity[s];
        *g4.into_inner() = grads.rotation[s];
        *g5.into_inner() = grads.scale[s];
        let (d_dc, d_rest) = split_sh(&grads.color[s]);
        *g6.into_inner() = Grad(d_dc);
        *deformed_out = deformed[s];
        put(state, n, 0, s, p0.into_inner(), a0.into_inner());
        put(state, n, 1, s, p1.into_inner(), a1.into_inner());
        put(state, n, 2, s, p2.into_inner(), a2.into_inner());
        put(state, n, 3, s, p3.into_inner(), a3.into_inner());
        put(state, n, 4, s, p4.into_inner(), a4.into_inner());
        put(state, n, 5, s, p5.into_inner(), a5.into_inner());
        let sh = |values| split_sh(&ResidentState::get::<ShCoefficients>(values, n, 6, s));
        let ((dc, rest), (m_dc, m_rest), (v_dc, v_rest)) =
            (sh(&state.params), sh(&state.m), sh(&state.v));
        *p6.into_inner() = dc;
        *a6.into_inner() = Adam { m: m_dc, v: v_dc };
        if let (Some(mut p7), Some(mut a7), Some(mut g7)) = (p7, a7, g7) {
            *p7 = rest;
            *a7 = Adam {
                m: m_rest,
                v: v_rest,
            };
            g7.0 = d_rest;
        }
        *accum = state.accum[s];
    }
    gpu.mark_dirty();
    Ok(())
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
