//! The photometric loss 0.8·L1 + 0.2·(1 − SSIM) and its gradient with respect to the render.

use bevy_ecs::prelude::*;

use crate::metrics::loss::{LossValue, training_loss};
use crate::resources::{
    CameraExposures, CoarseViews, LossImage, ReadFailure, ReadFault, Settings, SplatBuffers,
    TrainState, TrainingViews, ViewOrder, ViewSample, views_at,
};

/// Compares the render with the ground-truth image of the sampled view, recomposited over the
/// sampled background where that differs from the one the image was composited over. With
/// [`CameraExposures`] the render is first corrected by the sampled camera's exposure, and the
/// gradient is chained back through the correction (its own gradient kept for the Adam stage).
pub fn loss(
    settings: Res<Settings>,
    views: Res<TrainingViews>,
    coarse: Option<Res<CoarseViews>>,
    sample: Res<ViewSample>,
    buffers: Res<SplatBuffers>,
    exposures: Option<ResMut<CameraExposures>>,
    mut loss: ResMut<LossImage>,
    mut state: ResMut<TrainState>,
    mut read_fault: ResMut<ReadFault>,
    mut order: ResMut<ViewOrder>,
) {
    let index = sample.view.expect("training views come from the dataset");
    let loss = &mut *loss;
    let dataset = views_at(&views, coarse.as_deref(), state.iteration);
    let view = &dataset.train[index];
    if let Err(error) = view.copy_image_into(&mut loss.target) {
        // A streamed image that can no longer be read: a non-finite loss makes the numeric
        // guard stop the run before anything is updated; the trainer reports this error.
        read_fault.0.get_or_insert(ReadFailure {
            iteration: state.iteration,
            message: error.to_string(),
        });
        loss.d_color.clear();
        loss.d_color
            .resize(buffers.render.image.data.len(), [0.0; 3]);
        state.loss = LossValue {
            total: f32::NAN,
            ..LossValue::default()
        };
        return;
    }
    if let Some(matte) = &view.matte
        && sample.background != matte.background
    {
        matte.recomposite(&mut loss.target, sample.background);
    }
    let render = &buffers.render.image;
    let lambda_dssim = settings.train.lambda_dssim;
    loss.value = match exposures {
        None => training_loss(
            &mut loss.scratch,
            render,
            &loss.target,
            lambda_dssim,
            &mut loss.d_color,
        ),
        Some(mut exposures) => {
            let exposure = exposures.exposure(view.camera);
            exposure.apply(render, &mut loss.corrected);
            let value = training_loss(
                &mut loss.scratch,
                &loss.corrected,
                &loss.target,
                lambda_dssim,
                &mut loss.d_color,
            );
            let grad = exposure.backward(render, &mut loss.d_color);
            exposures.grad = Some((view.camera, grad));
            value
        }
    };
    state.loss = loss.value;
    // What `train.repeat_hard_views` ranks when the next epoch is drawn.
    if settings.train.repeat_hard_views > 0.0 && loss.value.total.is_finite() {
        order.losses.resize(dataset.train.len(), None);
        order.losses[index] = Some(loss.value.total);
    }
}
