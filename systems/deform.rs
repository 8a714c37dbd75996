//! Deformation to the sampled time: μ(t), q(t), s(t), σ(t) and the view-dependent colour.

use bevy_ecs::prelude::*;
use glam::Vec3;

use crate::components::{
    Deformed, MotionWeights, Opacity, ParamRefs, Temporal, TimeWindow, WarpedTime, sh_coefficients,
};
use crate::model::deform::{
    TemporalOpacity, fourier_offset, rotation_at, scale_at, scale_velocity, temporal_opacity,
    window_factor,
};
use crate::model::project::drawable;
use crate::model::sh::sh_to_rgb;
use crate::model::shared_motion::shared_offset;
use crate::resources::{DeformEveryGaussian, Settings, SharedMotion, TrainState, ViewSample};
use crate::systems::densify::counts_faded_views;
use crate::systems::smoothness::smoothness_enabled;

/// The components the deformation reads: the parameters, the warped time and, in merged
/// segment models, the time window.
pub type DeformInputs<'a> = (ParamRefs<'a>, &'a WarpedTime, Option<&'a TimeWindow>);

/// Whether a stage reads the deformed geometry of Gaussians too faded to draw: the baseline's
/// count of the views whose frustum holds a Gaussian, the motion-smoothness graph over the
/// deformed means, or a system of the user's ([`DeformEveryGaussian`]).
pub fn faded_geometry_read(settings: &Settings, every_gaussian: bool) -> bool {
    every_gaussian || counts_faded_views(&settings.densify) || smoothness_enabled(settings)
}

/// Evaluates every Gaussian at the sampled time into its [`Deformed`] component. A Gaussian
/// whose σ(t) is below what the splatting stage draws gets [`Deformed::faded`] unless
/// [`faded_geometry_read`]: on a real capture most Gaussians live a few frames, so at any
/// time most of them are faded, and their motion and colour would be evaluated for nothing.
///
/// With a [`SharedMotion`] resource (`model.shared_motion`) each Gaussian's mean also moves by
/// Σ_b w_b·u_b(t) (its [`MotionWeights`]; none without them), the bases evaluated once at the
/// view's time; the colour is seen from the moved mean.
pub fn deform(
    settings: Res<Settings>,
    state: Res<TrainState>,
    sample: Res<ViewSample>,
    every_gaussian: Option<Res<DeformEveryGaussian>>,
    shared: Option<Res<SharedMotion>>,
    mut gaussians: Query<(DeformInputs, Option<&MotionWeights>, &mut Deformed)>,
) {
    let skip_faded = !faded_geometry_read(&settings, every_gaussian.is_some());
    let motion = settings.motion_basis();
    let opacity_model = settings.opacity;
    let scale_motion = settings.model.scale_motion;
    let sh_degree = state.sh_degree;
    let eye = sample.camera.center();
    let time = sample.time;
    let bases_at = shared.map(|shared| shared.bases.evaluate(time));
    // Whole table columns at a time (as Adam does) rather than one entity at a time through
    // the query: the same arithmetic without the per-row component lookups.
    gaussians
        .contiguous_par_iter_mut()
        .expect("the deformation's components are stored in tables, so the query is dense")
        .for_each(|((params, warped, window), weights, mut out)| {
            let (pos, fourier, temporal, opacity, rotation, scale, color, rest) = params;
            for (i, out) in out.iter_mut().enumerate() {
                let warped = &warped[i];
                let window = window.map(|w| &w[i]);
                let dtw = warped.dtw;
                let opacity = opacity_at(
                    opacity_model,
                    &opacity[i],
                    &temporal[i],
                    warped,
                    window,
                    time,
                );
                if skip_faded && !drawable(opacity) {
                    *out = Deformed::faded(opacity);
                    continue;
                }
                let fourier = &fourier[i];
                let mut mean = Vec3::from_array(pos[i].mean)
                    + fourier_offset(&fourier.cos, &fourier.sin, &fourier.phase, motion, dtw);
                if let (Some(at), Some(weights)) = (&bases_at, weights) {
                    mean += shared_offset(&weights[i].w, at);
                }
                let (rotation, scale) = (&rotation[i], &scale[i]);
                let scale_velocity = scale_velocity(scale.d1, scale_motion);
                *out = Deformed {
                    mean: mean.to_array(),
                    rotation: rotation_at(rotation.c0, rotation.c1, dtw),
                    scale: scale_at(scale.d0, scale_velocity, dtw).to_array(),
                    opacity,
                    color: sh_to_rgb(
                        sh_degree,
                        &sh_coefficients(&color[i], rest.map(|r| &r[i])),
                        mean - eye,
                    ),
                };
            }
        });
}

/// σ(t) of one Gaussian at the sampled time `time` (its warped offset in `warped`), times its
/// segment window where it has one.
#[inline]
pub(crate) fn opacity_at(
    model: TemporalOpacity,
    opacity: &Opacity,
    temporal: &Temporal,
    warped: &WarpedTime,
    window: Option<&TimeWindow>,
    time: f32,
) -> f32 {
    temporal_opacity(model, opacity.logit, temporal.scale, warped.dtw)
        * window.map_or(1.0, |w| window_factor(w, time))
}
