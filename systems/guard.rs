//! The numeric guard: after the backward stage, every gradient must be finite. The first
//! non-finite value stops the iteration before Adam can write it into a parameter; the
//! [`NumericFault`] names the parameter group, the Gaussian and the iteration, and the
//! optimiser and densification stages do not run while it is set.

use bevy_ecs::prelude::*;
use rayon::prelude::*;

use bevy_ecs::schedule::ScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;

use crate::components::{Grad, MotionWeights, Param, each_param};
use crate::resources::{Fault, NumericFault, SharedMotion, TrainState};

/// Records a [`NumericFault`] when the loss is NaN or infinite.
pub fn check_loss(state: Res<TrainState>, mut fault: ResMut<NumericFault>) {
    if fault.0.is_none() && !state.loss.total.is_finite() {
        fault.0 = Some(Fault {
            iteration: state.iteration,
            group: "loss",
            gaussian: None,
        });
    }
}

/// Records a [`NumericFault`] naming the first Gaussian whose gradient of group `P` is NaN or
/// infinite, unless a fault is already recorded.
///
/// Every gradient value is read each iteration (30 M at 300 000 Gaussians of SH degree 3), so
/// the columns are checked as whole slices, a reduction the compiler vectorises; the Gaussian
/// is looked for only in a column that holds a bad value.
pub fn check_gradient<P: Param>(
    state: Res<TrainState>,
    mut fault: ResMut<NumericFault>,
    grads: Query<&Grad<P>>,
) {
    if fault.0.is_some() {
        return;
    }
    let mut first_row = 0;
    let columns = grads
        .contiguous_iter()
        .expect("gradient components are stored in tables, so the query is dense");
    for column in columns {
        if let Some(row) = first_non_finite_row(column) {
            fault.0 = Some(Fault {
                iteration: state.iteration,
                group: P::NAME,
                gaussian: Some(first_row + row),
            });
            return;
        }
        first_row += column.len();
    }
}

/// Records a [`NumericFault`] when the gradient of the shared motion bases
/// ([`SharedMotion::grad`]) holds a NaN or infinity, unless a fault is already recorded.
pub fn check_shared_motion(
    state: Res<TrainState>,
    mut fault: ResMut<NumericFault>,
    shared: Res<SharedMotion>,
) {
    if fault.0.is_none() && !all_finite(bytemuck::cast_slice(&shared.grad)) {
        fault.0 = Some(Fault {
            iteration: state.iteration,
            group: "shared motion bases' gradient",
            gaussian: None,
        });
    }
}

/// The first of consecutive Gaussians' gradients of group `P` that holds a NaN or infinity:
/// the whole slice is checked at once, and searched row by row only when it holds one.
pub(crate) fn first_non_finite_row<P: Param>(grads: &[Grad<P>]) -> Option<usize> {
    let values: &[f32] = bytemuck::cast_slice(grads);
    if all_finite(values) {
        return None;
    }
    let row = values
        .chunks_exact(P::FLOATS)
        .position(|g| !all_finite(g))
        .expect("a slice with a bad value has a row with one");
    Some(row)
}

/// Whether no value is NaN or infinite: no magnitude's bits, as a signed integer, above those
/// of the largest finite value. A comparison and an OR per value, which the baseline x86-64
/// build vectorises too (it has no 32-bit integer maximum), over chunks of the slice in
/// parallel (the guard reads every gradient each iteration).
fn all_finite(values: &[f32]) -> bool {
    const LARGEST_FINITE_BITS: i32 = 0x7f7f_ffff;
    const CHUNK: usize = 1 << 16;
    let finite = |chunk: &[f32]| {
        let beyond = chunk.iter().fold(0u32, |beyond, v| {
            beyond | (((v.to_bits() & 0x7fff_ffff) as i32 > LARGEST_FINITE_BITS) as u32)
        });
        beyond == 0
    };
    if values.len() <= CHUNK {
        return finite(values);
    }
    values.par_chunks(CHUNK).all(finite)
}

/// The systems of the guard, for ordering your own systems before or after it.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct GradientGuard;

/// The guard, in [`GradientGuard`]: [`check_loss`], then [`check_gradient`] of every parameter
/// group in declaration order ([`crate::components::param_groups!`]), so the fault names the
/// first bad group; then, with shared motion ([`SharedMotion`]), the weights' and the bases'
/// gradients.
pub fn check_gradients() -> ScheduleConfigs<ScheduleSystem> {
    macro_rules! checks {
        ($($group:ty,)*) => {
            (check_loss, $(check_gradient::<$group>,)*).chain()
        };
    }
    (
        each_param!(checks),
        (check_gradient::<MotionWeights>, check_shared_motion)
            .chain()
            .run_if(resource_exists::<SharedMotion>),
    )
        .chain()
        .in_set(GradientGuard)
}

/// Run condition: no numeric fault has been recorded.
pub fn healthy(fault: Res<NumericFault>) -> bool {
    fault.0.is_none()
}

#[cfg(test)]
mod tests {
    use super::all_finite;

    /// Finite values of any sign and size pass; one NaN or infinity anywhere fails.
    #[test]
    fn all_finite_finds_any_nan_or_infinity() {
        let finite = [
            0.0,
            -0.0,
            1.0,
            -f32::MAX,
            f32::MAX,
            f32::MIN_POSITIVE,
            1e-45,
            -3.5,
        ];
        assert!(all_finite(&finite));
        assert!(all_finite(&[]));
        for bad in [f32::NAN, -f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            for at in 0..finite.len() {
                let mut values = finite.to_vec();
                values.insert(at, bad);
                assert!(!all_finite(&values), "{bad} at {at}");
            }
        }
    }

    /// A slice long enough to be checked in parallel chunks: one bad value is found in the
    /// first, a middle or the last chunk, at a chunk's edges too.
    #[test]
    fn all_finite_finds_a_bad_value_in_any_chunk() {
        let len = 5 * (1 << 16) + 123;
        let mut values: Vec<f32> = (0..len).map(|i| (i as f32).sin() * 1e30).collect();
        assert!(all_finite(&values));
        for at in [0, (1 << 16) - 1, 1 << 16, 3 * (1 << 16) + 7, len - 1] {
            for bad in [f32::NAN, f32::NEG_INFINITY] {
                let kept = std::mem::replace(&mut values[at], bad);
                assert!(!all_finite(&values), "{bad} at {at}");
                values[at] = kept;
            }
        }
    }
}
