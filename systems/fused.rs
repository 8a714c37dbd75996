//! Fused Adam (`train.fused_adam`): the chain rule through the deformation model, the numeric
//! guard and the Adam step of every parameter group in one pass over the Gaussians, a block
//! of rows at a time, each block's gradients kept on the stack.
//!
//! The unfused stages write every Gaussian's gradient into its `Grad` components
//! ([`crate::systems::backward::backward_parameters`]), read them all again to check them
//! ([`crate::systems::guard::check_gradients`]) and once more to step them
//! ([`crate::systems::adam::adam_step`]). Gaussians spawned under `train.fused_adam` have no
//! `Grad` components (a third of their memory at SH degree 3), so those systems find none of
//! them, and [`backward_and_step`] does the three stages' work for them instead, with the
//! same arithmetic: the model is the same bit for bit.

use std::sync::Mutex;

use bevy_ecs::prelude::*;

use crate::components::{
    AdamClock, AdamMuts, Color, ColorRest, Deformed, Fourier, Grad, Opacity, Param, ParamMuts,
    Position, Rotation, Scale, SplatSlot, Temporal, TimeWindow, WarpedTime,
};
use crate::model::adam::DeferredSums;
use crate::resources::{Fault, NumericFault, Settings, SplatBuffers, TrainState, ViewSample};
use crate::systems::adam::GroupStep;
use crate::systems::backward::{ChainRows, ChainRule, RowGrads};
use crate::systems::guard::first_non_finite_row;

/// Rows chained and stepped together: their gradients (388 bytes a Gaussian at SH degree 3)
/// stay in the first-level cache between the chain rule and the step.
const BLOCK: usize = 64;

/// What else the chain rule and the step read of a Gaussian.
type RowInputs<'a> = (
    &'a WarpedTime,
    Option<&'a TimeWindow>,
    &'a Deformed,
    &'a SplatSlot,
    Option<&'a AdamClock>,
);

/// One block's gradients.
struct BlockGrads {
    position: [Grad<Position>; BLOCK],
    fourier: [Grad<Fourier>; BLOCK],
    temporal: [Grad<Temporal>; BLOCK],
    opacity: [Grad<Opacity>; BLOCK],
    rotation: [Grad<Rotation>; BLOCK],
    scale: [Grad<Scale>; BLOCK],
    color: [Grad<Color>; BLOCK],
    rest: [Grad<ColorRest>; BLOCK],
}

impl BlockGrads {
    fn new() -> Self {
        Self {
            position: [Grad::default(); BLOCK],
            fourier: [Grad::default(); BLOCK],
            temporal: [Grad::default(); BLOCK],
            opacity: [Grad::default(); BLOCK],
            rotation: [Grad::default(); BLOCK],
            scale: [Grad::default(); BLOCK],
            color: [Grad::default(); BLOCK],
            rest: [Grad::default(); BLOCK],
        }
    }

    /// The first `rows` rows, as the chain rule writes them.
    fn rows(&mut self, rows: usize, rest: bool) -> RowGrads<'_> {
        RowGrads {
            position: &mut self.position[..rows],
            fourier: &mut self.fourier[..rows],
            temporal: &mut self.temporal[..rows],
            opacity: &mut self.opacity[..rows],
            rotation: &mut self.rotation[..rows],
            scale: &mut self.scale[..rows],
            color: &mut self.color[..rows],
            rest: rest.then_some(&mut self.rest[..rows]),
        }
    }

    /// The first group, in declaration order, of the first `rows` rows with a NaN or infinite
    /// gradient, with its first such row.
    fn first_fault(&self, rows: usize, rest: bool) -> Option<(usize, &'static str, usize)> {
        fn bad<P: Param>(grads: &[Grad<P>]) -> Option<(usize, &'static str, usize)> {
            first_non_finite_row(grads).map(|row| (P::INDEX, P::NAME, row))
        }
        bad(&self.position[..rows])
            .or_else(|| bad(&self.fourier[..rows]))
            .or_else(|| bad(&self.temporal[..rows]))
            .or_else(|| bad(&self.opacity[..rows]))
            .or_else(|| bad(&self.rotation[..rows]))
            .or_else(|| bad(&self.scale[..rows]))
            .or_else(|| bad(&self.color[..rows]))
            .or_else(|| rest.then(|| bad(&self.rest[..rows])).flatten())
    }
}

/// This iteration's step of every group.
struct Steps<'a> {
    position: GroupStep<'a, Position>,
    fourier: GroupStep<'a, Fourier>,
    temporal: GroupStep<'a, Temporal>,
    opacity: GroupStep<'a, Opacity>,
    rotation: GroupStep<'a, Rotation>,
    scale: GroupStep<'a, Scale>,
    color: GroupStep<'a, Color>,
    rest: GroupStep<'a, ColorRest>,
}

/// For the Gaussians without gradient components (`train.fused_adam`), in the Adam stage:
/// chains each one's deformed-Gaussian gradient (from
/// [`crate::systems::backward::backward_splats`]) through the deformation model, checks it as
/// the numeric guard does, and steps Adam on it, as `backward_parameters`, `check_gradients`
/// and `adam_step` do for Gaussians with gradient components (dense, visible or deferred
/// Adam alike, with the same rates, bias correction and rounding).
///
/// A NaN or infinite gradient records the same [`NumericFault`] as the guard (the first group
/// in declaration order, then the first Gaussian); the block of rows that holds it is left
/// unstepped, but other blocks may have been stepped already: the parameters never take a
/// non-finite gradient, and training stops at the fault as it does unfused.
#[allow(clippy::type_complexity)]
pub fn backward_and_step(
    settings: Res<Settings>,
    state: Res<TrainState>,
    sample: Res<ViewSample>,
    buffers: Res<SplatBuffers>,
    mut fault: ResMut<NumericFault>,
    mut sums: Local<[DeferredSums; 8]>,
    mut gaussians: Query<(ParamMuts, AdamMuts, RowInputs), Without<Grad<Position>>>,
) {
    if gaussians.is_empty() {
        return;
    }
    let chain = ChainRule::for_view(&settings, &state, &sample);
    let [s0, s1, s2, s3, s4, s5, s6, s7] = &mut *sums;
    let deformed_grads = &buffers.deformed_grads;
    let buffers = Some(&*buffers);
    let steps = Steps {
        position: GroupStep::new(&settings, &state, buffers, s0),
        fourier: GroupStep::new(&settings, &state, buffers, s1),
        temporal: GroupStep::new(&settings, &state, buffers, s2),
        opacity: GroupStep::new(&settings, &state, buffers, s3),
        rotation: GroupStep::new(&settings, &state, buffers, s4),
        scale: GroupStep::new(&settings, &state, buffers, s5),
        color: GroupStep::new(&settings, &state, buffers, s6),
        rest: GroupStep::new(&settings, &state, buffers, s7),
    };
    // The smallest (group, Gaussian) with a bad gradient, over the parallel chunks.
    let first_fault = Mutex::new(None::<(usize, &'static str, usize)>);
    gaussians
        .contiguous_par_iter_mut()
        .expect("Gaussian components are stored in tables, so the query is dense")
        .for_each(|(params, moments, inputs)| {
            let (mut p0, mut p1, mut p2, mut p3, mut p4, mut p5, mut p6, mut p7) = params;
            let (mut m0, mut m1, mut m2, mut m3, mut m4, mut m5, mut m6, mut m7) = moments;
            // Each column dereferenced once: every mutable dereference marks it changed.
            let (position, fourier, temporal, opacity) =
                (&mut p0[..], &mut p1[..], &mut p2[..], &mut p3[..]);
            let (rotation, scale, color) = (&mut p4[..], &mut p5[..], &mut p6[..]);
            let mut rest = p7.as_mut().map(|r| &mut r[..]);
            let (m_position, m_fourier, m_temporal, m_opacity) =
                (&mut m0[..], &mut m1[..], &mut m2[..], &mut m3[..]);
            let (m_rotation, m_scale, m_color) = (&mut m4[..], &mut m5[..], &mut m6[..]);
            let mut m_rest = m7.as_mut().map(|m| &mut m[..]);
            let (warped, windows, deformed, slots, clocks) = inputs;
            let has_rest = rest.is_some();

            let mut grads = BlockGrads::new();
            for start in (0..slots.len()).step_by(BLOCK) {
                let r = start..(start + BLOCK).min(slots.len());
                let n = r.len();
                let rows = ChainRows {
                    params: (
                        &position[r.clone()],
                        &fourier[r.clone()],
                        &temporal[r.clone()],
                        &opacity[r.clone()],
                        &rotation[r.clone()],
                        &scale[r.clone()],
                        &color[r.clone()],
                        rest.as_deref().map(|c| &c[r.clone()]),
                    ),
                    warped: &warped[r.clone()],
                    windows: windows.map(|w| &w[r.clone()]),
                    deformed: &deformed[r.clone()],
                    slots: &slots[r.clone()],
                };
                chain.rows(rows, deformed_grads, &mut grads.rows(n, has_rest));
                if let Some((group, name, row)) = grads.first_fault(n, has_rest) {
                    let found = (group, name, slots[start + row].0 as usize);
                    let mut first = first_fault.lock().unwrap_or_else(|e| e.into_inner());
                    if first.is_none_or(|f| (found.0, found.2) < (f.0, f.2)) {
                        *first = Some(found);
                    }
                    continue;
                }
                let (slots, clocks) = (Some(&slots[r.clone()]), clocks.map(|c| &c[r.clone()]));
                macro_rules! step {
                    ($group:ident, $values:expr, $moments:expr) => {
                        steps.$group.rows(
                            &mut $values[r.clone()],
                            &grads.$group[..n],
                            &mut $moments[r.clone()],
                            slots,
                            clocks,
                        )
                    };
                }
                step!(position, position, m_position);
                step!(fourier, fourier, m_fourier);
                step!(temporal, temporal, m_temporal);
                step!(opacity, opacity, m_opacity);
                step!(rotation, rotation, m_rotation);
                step!(scale, scale, m_scale);
                step!(color, color, m_color);
                if let (Some(rest), Some(m_rest)) = (rest.as_deref_mut(), m_rest.as_deref_mut()) {
                    step!(rest, rest, m_rest);
                }
            }
        });
    let first = first_fault.into_inner().unwrap_or_else(|e| e.into_inner());
    if let Some((_, group, gaussian)) = first
        && fault.0.is_none()
    {
        fault.0 = Some(Fault {
            iteration: state.iteration,
            group,
            gaussian: Some(gaussian),
        });
    }
}
