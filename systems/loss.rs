//! The photometric loss 0.8·L1 + 0.2·(1 − SSIM) and its gradient with respect to the render.

use bevy_ecs::prelude::*;

use crate::metrics::loss::training_loss;
use crate::resources::{
    CoarseViews, LossImage, Settings, SplatBuffers, TrainState, TrainingViews, ViewSample, views_at,
};

/// Compares the render with the ground-truth image of the sampled view.
pub fn loss(
    settings: Res<Settings>,
    views: Res<TrainingViews>,
    coarse: Option<Res<CoarseViews>>,
    sample: Res<ViewSample>,
    buffers: Res<SplatBuffers>,
    mut loss: ResMut<LossImage>,
    mut state: ResMut<TrainState>,
) {
    let index = sample.view.expect("training views come from the dataset");
    let loss = &mut *loss;
    let dataset = views_at(&views, coarse.as_deref(), state.iteration);
    dataset.train[index].copy_image_into(&mut loss.target);
    loss.value = training_loss(
        &mut loss.scratch,
        &buffers.render.image,
        &loss.target,
        settings.train.lambda_dssim,
        &mut loss.d_color,
    );
    state.loss = loss.value;
}
