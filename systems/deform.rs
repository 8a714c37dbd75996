//! Deformation to the sampled time: μ(t), q(t), s(t), σ(t) and the view-dependent colour.

use bevy_ecs::prelude::*;
use glam::Vec3;

use crate::components::{Deformed, ParamRefs, TimeWindow, WarpedTime, sh_coefficients};
use crate::model::deform::{
    fourier_offset, rotation_at, scale_at, scale_velocity, temporal_opacity, window_factor,
};
use crate::model::sh::sh_to_rgb;
use crate::resources::{Settings, TrainState, ViewSample};

/// The components the deformation reads: the parameters, the warped time and, in merged
/// segment models, the time window.
pub type DeformInputs<'a> = (ParamRefs<'a>, &'a WarpedTime, Option<&'a TimeWindow>);

/// Evaluates every Gaussian at the sampled time into its [`Deformed`] component.
pub fn deform(
    settings: Res<Settings>,
    state: Res<TrainState>,
    sample: Res<ViewSample>,
    mut gaussians: Query<(DeformInputs, &mut Deformed)>,
) {
    let motion = settings.motion_basis();
    let opacity_model = settings.opacity;
    let scale_motion = settings.model.scale_motion;
    let sh_degree = state.sh_degree;
    let eye = sample.camera.center();
    let time = sample.time;
    gaussians.par_iter_mut().for_each(
        |(
            ((pos, fourier, temporal, opacity, rotation, scale, color, rest), warped, window),
            mut out,
        )| {
            let dtw = warped.dtw;
            let mean = Vec3::from_array(pos.mean)
                + fourier_offset(&fourier.cos, &fourier.sin, &fourier.phase, motion, dtw);
            let scale_velocity = scale_velocity(scale.d1, scale_motion);
            *out = Deformed {
                mean: mean.to_array(),
                rotation: rotation_at(rotation.c0, rotation.c1, dtw),
                scale: scale_at(scale.d0, scale_velocity, dtw).to_array(),
                opacity: temporal_opacity(opacity_model, opacity.logit, temporal.scale, dtw)
                    * window.map_or(1.0, |w| window_factor(w, time)),
                color: sh_to_rgb(sh_degree, &sh_coefficients(color, rest), mean - eye),
            };
        },
    );
}
