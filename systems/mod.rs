//! The training stages as bevy_ecs systems, in the order of one iteration:
//!
//! `sample_view → time_warp → deform → splat → loss → backward → adam → densify`
//!
//! Each stage is a [`TrainSet`]; [`training_schedule`] chains the sets once. Structural changes
//! (spawn on clone/split, despawn on prune) happen only in [`TrainSet::Densify`].
//!
//! With a [`crate::gpu::GpuTraining`] resource (`backend: Gpu`) the [`resident`] systems run in
//! the Splat, Backward, Adam and Densify sets instead of the CPU deformation, splatting,
//! backward, guard, Adam and statistics systems (run conditions [`resident::on_gpu`] and
//! [`resident::on_cpu`]); sample view, time warp, loss and densification stay on the CPU.
//! Edits of components by systems of your own are honoured on both backends or refused with
//! an error on the GPU one (see [`resident`]: [`resident::HostGradients`] for gradient edits,
//! [`resident::resident_sync`] before parameter edits).

pub mod adam;
pub mod backward;
pub mod deform;
pub mod densify;
pub mod describe;
pub mod guard;
pub mod loss;
pub mod resident;
pub mod sample_view;
pub mod splat;
pub mod time_warp;

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{ScheduleLabel, SingleThreadedExecutor};

/// The stages of one training iteration, in order.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TrainSet {
    /// Counts the iteration, raises the SH degree on schedule and picks the (camera, frame)
    /// view into [`crate::resources::ViewSample`].
    SampleView,
    /// Writes each Gaussian's [`crate::components::WarpedTime`] (TOW).
    TimeWarp,
    /// Evaluates each Gaussian at the sampled time into [`crate::components::Deformed`].
    Deform,
    /// Projects (EWA) and rasterizes the deformed Gaussians into
    /// [`crate::resources::SplatBuffers`].
    Splat,
    /// Computes the photometric loss and its image gradient into
    /// [`crate::resources::LossImage`].
    Loss,
    /// Differentiates blending and projection, writes every [`crate::components::Grad`] and
    /// runs the numeric guard.
    Backward,
    /// One Adam step per parameter group (skipped after a numeric fault).
    Adam,
    /// Accumulates densification statistics, clones, splits and prunes on schedule, resets
    /// opacities (skipped after a numeric fault); the only structural changes.
    Densify,
}

/// Label of the schedule returned by [`training_schedule`].
#[derive(ScheduleLabel, Debug, Clone, PartialEq, Eq, Hash)]
pub struct TrainIteration;

/// Label of the schedule returned by [`render_schedule`].
#[derive(ScheduleLabel, Debug, Clone, PartialEq, Eq, Hash)]
pub struct RenderView;

/// Adds every training system to `schedule`, each in its [`TrainSet`], with the sets chained.
///
/// Use this to put the tadgs stages into a schedule of your own; insert your systems between
/// stages with `.after(TrainSet::X).before(TrainSet::Y)`.
pub fn add_training_systems(schedule: &mut Schedule) {
    use TrainSet::*;
    schedule.configure_sets(
        (
            SampleView, TimeWarp, Deform, Splat, Loss, Backward, Adam, Densify,
        )
            .chain(),
    );
    schedule.add_systems(
        (sample_view::advance_iteration, sample_view::sample_view)
            .chain()
            .in_set(SampleView),
    );
    add_render_systems(schedule);
    add_gradient_systems(schedule);
    // A NaN or infinity found after the backward pass must not reach the parameters.
    schedule.configure_sets((Adam, Densify).run_if(guard::healthy));
    schedule.add_systems(adam::adam_systems().run_if(resident::on_cpu).in_set(Adam));
    // Both backends: the loss, and so the exposure gradient, is on the CPU.
    schedule.add_systems(adam::adam_exposure.in_set(Adam));
    schedule.add_systems(
        (resident::resident_gradients_in, resident::resident_adam)
            .chain()
            .run_if(resident::on_gpu)
            .in_set(Adam),
    );
    schedule.add_systems(densify::densify_systems().in_set(Densify));
}

/// Adds the stages that draw the current [`crate::resources::ViewSample`]: time warp,
/// deformation and splatting.
pub fn add_render_systems(schedule: &mut Schedule) {
    use TrainSet::*;
    schedule.configure_sets((TimeWarp, Deform, Splat).chain());
    schedule.add_systems(time_warp::time_warp.in_set(TimeWarp));
    schedule.add_systems(deform::deform.run_if(resident::on_cpu).in_set(Deform));
    schedule.add_systems(splat::splat.run_if(resident::on_cpu).in_set(Splat));
    schedule.add_systems(
        (resident::resident_upload, resident::resident_forward)
            .chain()
            .run_if(resident::on_gpu)
            .in_set(Splat),
    );
}

/// Adds the loss and backward stages (after splatting).
fn add_gradient_systems(schedule: &mut Schedule) {
    schedule.add_systems(loss::loss.in_set(TrainSet::Loss));
    add_backward_systems(schedule);
}

/// Adds the backward stage, which reads the image gradient from
/// [`crate::resources::LossImage`]: with [`add_render_systems`] and a loss of your own in
/// [`TrainSet::Loss`], it differentiates any image loss.
pub fn add_backward_systems(schedule: &mut Schedule) {
    use TrainSet::*;
    schedule.configure_sets((Splat, Loss, Backward).chain());
    schedule.add_systems(
        (
            backward::backward_splats,
            backward::backward_parameters,
            guard::check_gradients(),
        )
            .chain()
            .run_if(resident::on_cpu)
            .in_set(Backward),
    );
    schedule.add_systems(
        (
            resident::resident_backward,
            resident::resident_gradients_out,
        )
            .chain()
            .run_if(resident::on_gpu)
            .in_set(Backward),
    );
}

/// The schedule of one training iteration.
pub fn training_schedule() -> Schedule {
    let mut schedule = Schedule::new(TrainIteration);
    schedule.set_executor(SingleThreadedExecutor::new());
    add_training_systems(&mut schedule);
    schedule
}

/// The schedule that renders the current [`crate::resources::ViewSample`] without training:
/// time warp, deformation and splatting.
pub fn render_schedule() -> Schedule {
    let mut schedule = Schedule::new(RenderView);
    schedule.set_executor(SingleThreadedExecutor::new());
    add_render_systems(&mut schedule);
    schedule
}

/// Label of the schedule returned by [`gradient_schedule`].
#[derive(ScheduleLabel, Debug, Clone, PartialEq, Eq, Hash)]
pub struct ComputeGradients;

/// Renders the current [`crate::resources::ViewSample`] (which must be a dataset view), computes
/// the loss and writes every [`crate::components::Grad`] without changing any parameter.
pub fn gradient_schedule() -> Schedule {
    let mut schedule = Schedule::new(ComputeGradients);
    schedule.set_executor(SingleThreadedExecutor::new());
    add_render_systems(&mut schedule);
    add_gradient_systems(&mut schedule);
    schedule
}
