//! Gradients from the image back to every parameter component.

use bevy_ecs::prelude::*;
use glam::Vec3;
use rayon::prelude::*;

use crate::components::{
    Color, ColorRest, Deformed, Fourier, Grad, Opacity, Position, Rotation, Scale, SplatSlot,
    Temporal, sh_coefficients, split_sh,
};
use crate::gpu::GpuRasterizer;
use crate::model::deform::{
    centre_gradient, fourier_offset_backward, polynomial_dtw_backward, rotation_at_backward,
    scale_at_backward, scale_velocity, temporal_opacity_backward, temporal_opacity_dtw_backward,
    window_factor,
};
use crate::model::project::project_backward;
use crate::model::sh::sh_to_rgb_backward;
use crate::raster::SplatGrad;
use crate::resources::{DeformedGrad, LossImage, Settings, SplatBuffers, TrainState, ViewSample};
use crate::systems::deform::DeformInputs;
use crate::systems::densify::ndc_gradient_norm;

/// Back-propagates the image gradient through blending and projection to each slot's deformed
/// Gaussian, and records the NDC-space 2D mean gradient norm used by densification. Blending
/// is differentiated on the GPU when there is a [`GpuRasterizer`] resource.
pub fn backward_splats(
    sample: Res<ViewSample>,
    loss: Res<LossImage>,
    mut buffers: ResMut<SplatBuffers>,
    gpu: Option<ResMut<GpuRasterizer>>,
) -> Result {
    let buffers = &mut *buffers;
    let camera = sample.camera;
    let width = camera.width as usize;
    match gpu {
        Some(mut gpu) => gpu.backward(&buffers.splats, &loss.d_color, &mut buffers.splat_grads)?,
        None => buffers.rasterizer.backward(
            &buffers.splats,
            &loss.d_color,
            width,
            &mut buffers.splat_grads,
        ),
    }

    // The densification statistics' gradient sample, while the splat gradients are at hand.
    let half = glam::Vec2::new(0.5 * camera.width as f32, 0.5 * camera.height as f32);
    buffers
        .splats
        .par_iter()
        .zip(&buffers.splat_grads)
        .map(|(s, g)| ndc_gradient_norm(s, g, half))
        .collect_into_vec(&mut buffers.ndc_grad_norm);

    buffers
        .deformed
        .par_iter()
        .zip(&buffers.splats)
        .zip(&buffers.splat_grads)
        .map(|((d, s), g)| {
            // Splats behind opaque pixels get no gradient: nothing to chain back.
            if !s.visible || *g == SplatGrad::default() {
                return (DeformedGrad::default(), false);
            }
            let p = project_backward(
                Vec3::from_array(d.mean),
                d.rotation,
                Vec3::from_array(d.scale),
                &camera,
                g.mean2d,
                g.conic,
            );
            let grad = DeformedGrad {
                mean: p.mean,
                rotation: p.quat,
                scale: p.scale,
                opacity: g.opacity,
                color: g.color,
            };
            (grad, grad != DeformedGrad::default())
        })
        .unzip_into_vecs(&mut buffers.deformed_grads, &mut buffers.gradient_reached);
    Ok(())
}

/// The gradient components written by the backward pass.
pub type ParamGrads<'a> = (
    &'a mut Grad<Position>,
    &'a mut Grad<Fourier>,
    &'a mut Grad<Temporal>,
    &'a mut Grad<Opacity>,
    &'a mut Grad<Rotation>,
    &'a mut Grad<Scale>,
    &'a mut Grad<Color>,
    Option<&'a mut Grad<ColorRest>>,
);

/// Chains each deformed Gaussian's gradient through the deformation model to its parameters.
pub fn backward_parameters(
    settings: Res<Settings>,
    state: Res<TrainState>,
    sample: Res<ViewSample>,
    buffers: Res<SplatBuffers>,
    mut gaussians: Query<(DeformInputs, &Deformed, &SplatSlot, ParamGrads)>,
) {
    let motion = settings.motion_basis();
    let opacity_model = settings.opacity;
    let scale_motion = settings.model.scale_motion;
    let learn_centres = settings.train.lr.temporal_center > 0.0;
    let warp = settings.warp;
    let sh_degree = state.sh_degree;
    let eye = sample.camera.center();
    gaussians
        .par_iter_mut()
        .for_each(|(inputs, deformed, slot, grads)| {
            let ((_, fourier, temporal, opacity, rotation, scale, color, rest), warped, window) =
                inputs;
            let (
                mut g_pos,
                mut g_fourier,
                mut g_temporal,
                mut g_opacity,
                mut g_rotation,
                mut g_scale,
                mut g_color,
                g_rest,
            ) = grads;
            let d = buffers.deformed_grads[slot.0 as usize];
            if d == DeformedGrad::default() {
                // Not drawn, or drawn only behind opaque pixels (most Gaussians of a dense
                // scene): no gradient reaches its parameters, so the chain rule is skipped.
                *g_pos = Grad::default();
                *g_fourier = Grad::default();
                *g_temporal = Grad::default();
                *g_opacity = Grad::default();
                *g_rotation = Grad::default();
                *g_scale = Grad::default();
                *g_color = Grad::default();
                if let Some(mut g_rest) = g_rest {
                    *g_rest = Grad::default();
                }
                return;
            }
            let dtw = warped.dtw;
            // A time window scales σ(t) by a factor of time alone: dL/dσ scales alike.
            let d_sigma = d.opacity * window.map_or(1.0, |w| window_factor(w, sample.time));

            let (d_sh, d_dir) = sh_to_rgb_backward(
                sh_degree,
                &sh_coefficients(color, rest),
                deformed.mean() - eye,
                d.color,
            );
            let d_mean = d.mean + d_dir;
            let f = fourier_offset_backward(
                &fourier.cos,
                &fourier.sin,
                &fourier.phase,
                motion,
                dtw,
                d_mean,
            );
            let (d_c0, d_c1) = rotation_at_backward(rotation.c0, rotation.c1, dtw, d.rotation);
            let scale_velocity = scale_velocity(scale.d1, scale_motion);
            let (d_d0, mut d_d1) = scale_at_backward(scale.d0, scale_velocity, dtw, d.scale);
            if !scale_motion {
                d_d1 = [0.0; 3];
            }
            let (d_logit, d_raw) = temporal_opacity_backward(
                opacity_model,
                opacity.logit,
                temporal.scale,
                dtw,
                d_sigma,
            );

            g_pos.0 = Position {
                mean: d_mean.to_array(),
            };
            g_fourier.0 = Fourier {
                cos: f.cos,
                sin: f.sin,
                phase: f.phase,
            };
            // The centre's gradient only where it is learnt: as a constant it has none.
            let center = if learn_centres {
                let d_dtw = f.dtw
                    + polynomial_dtw_backward(d_c0, rotation.c1, d_d0, scale_velocity)
                    + temporal_opacity_dtw_backward(
                        opacity_model,
                        opacity.logit,
                        temporal.scale,
                        dtw,
                        d_sigma,
                    );
                centre_gradient(d_dtw, &warp, temporal.center, warped.dt)
            } else {
                0.0
            };
            g_temporal.0 = Temporal {
                center,
                scale: d_raw,
            };
            g_opacity.0 = Opacity { logit: d_logit };
            g_rotation.0 = Rotation { c0: d_c0, c1: d_c1 };
            g_scale.0 = Scale { d0: d_d0, d1: d_d1 };
            let (d_dc, d_rest) = split_sh(&d_sh);
            g_color.0 = d_dc;
            if let Some(mut g_rest) = g_rest {
                g_rest.0 = d_rest;
            }
        });
}
