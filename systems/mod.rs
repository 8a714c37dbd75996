//! The training stages as bevy_ecs systems, in the order of one iteration:
//!
//! `sample_view → time_warp → deform → splat → loss → backward → adam → densify`
//!
//! Each stage is a [`TrainSet`]; [`training_schedule`] chains the sets once. Structural changes
//! (spawn on clone/split, despawn on prune) happen only in [`TrainSet::Densify`].
//!
//! The stages whose work differs between backends (deformation, splatting, backward and guard,
//! Adam, the densification statistics) are installed by a [`BackendPlugin`]: [`CpuBackend`],
//! or [`resident::GpuResidentBackend`], which runs them on the GPU when the world holds a
//! [`crate::gpu::GpuTraining`] resource (`backend: Gpu`). Each plugin puts its systems into the
//! same [`TrainSet`]s under its own run condition, so no stage's system asks which backend
//! runs; sample view, time warp, loss and the structural part of densification are shared.
//! Edits of components by systems of your own are honoured on both backends or refused with
//! an error on the GPU one (see [`resident`]: [`resident::HostGradients`] for gradient edits,
//! [`resident::resident_sync`] before parameter edits).

pub mod adam;
pub mod backward;
pub mod deform;
pub mod densify;
pub mod describe;
pub mod fused;
pub mod guard;
pub mod loss;
pub mod prefetch;
pub mod resident;
pub mod sample_view;
pub mod smoothness;
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
    // Both backends: the loss, and so the exposure gradient, is on the CPU.
    schedule.add_systems(adam::adam_exposure.in_set(Adam));
    schedule.add_systems(densify::densify_systems().in_set(Densify));
    for backend in BACKENDS {
        backend.add_update_systems(schedule);
    }
}

/// One backend: installs the systems of the stages whose work differs between backends into
/// their [`TrainSet`]s, each under the backend's run condition (so a world runs exactly one
/// backend's systems, chosen by its resources).
pub trait BackendPlugin: Sync {
    /// [`TrainSet::Deform`] and [`TrainSet::Splat`]: the sampled view into
    /// [`crate::resources::SplatBuffers::render`].
    fn add_render_systems(&self, schedule: &mut Schedule);
    /// [`TrainSet::Backward`]: every [`crate::components::Grad`] (or its GPU copy) from
    /// [`crate::resources::LossImage`], and the numeric guard.
    fn add_backward_systems(&self, schedule: &mut Schedule);
    /// [`TrainSet::Adam`] for the parameter groups, and in [`TrainSet::Densify`] the
    /// statistics and whatever must happen before the shared systems change the population
    /// ([`densify::densify_and_prune`], [`densify::reset_opacity`]).
    fn add_update_systems(&self, schedule: &mut Schedule);
}

/// Every backend a training schedule carries; the world's resources pick the one that runs.
pub const BACKENDS: [&dyn BackendPlugin; 2] = [&CpuBackend, &resident::GpuResidentBackend];

/// The CPU backend (rayon): runs when the world has no [`crate::gpu::GpuTraining`]. Blending
/// runs on the GPU instead when the world holds a [`crate::gpu::GpuRasterizer`], an
/// accelerator for this backend's splatting and backward systems.
pub struct CpuBackend;

impl BackendPlugin for CpuBackend {
    fn add_render_systems(&self, schedule: &mut Schedule) {
        use TrainSet::*;
        schedule.add_systems(deform::deform.run_if(resident::on_cpu).in_set(Deform));
        schedule.add_systems(splat::splat.run_if(resident::on_cpu).in_set(Splat));
    }

    fn add_backward_systems(&self, schedule: &mut Schedule) {
        schedule.add_systems(
            (
                backward::backward_splats,
                backward::backward_parameters,
                smoothness::motion_smoothness.run_if(smoothness::smoothing),
                backward::backward_shared_motion
                    .run_if(resource_exists::<crate::resources::SharedMotion>),
                guard::check_gradients(),
            )
                .chain()
                .run_if(resident::on_cpu)
                .in_set(TrainSet::Backward),
        );
    }

    fn add_update_systems(&self, schedule: &mut Schedule) {
        use TrainSet::*;
        // Training only (not in render schedules): deferred Adam's catch-up before drawing.
        schedule.add_systems(
            adam::catch_up_systems()
                .run_if(resident::on_cpu)
                .in_set(Deform)
                .before(deform::deform),
        );
        schedule.add_systems(adam::adam_systems().run_if(resident::on_cpu).in_set(Adam));
        schedule.add_systems(
            densify::accumulate_stats
                .run_if(densify::densifying)
                .run_if(resident::on_cpu)
                .in_set(Densify)
                .before(densify::densify_and_prune),
        );
    }
}

/// Adds the stages that draw the current [`crate::resources::ViewSample`]: time warp,
/// deformation and splatting.
pub fn add_render_systems(schedule: &mut Schedule) {
    use TrainSet::*;
    schedule.configure_sets((TimeWarp, Deform, Splat).chain());
    schedule.add_systems(time_warp::time_warp.in_set(TimeWarp));
    for backend in BACKENDS {
        backend.add_render_systems(schedule);
    }
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
    for backend in BACKENDS {
        backend.add_backward_systems(schedule);
    }
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
