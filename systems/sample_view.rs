//! Picks the training view (camera, frame) of the iteration and advances the counters.

use bevy_ecs::prelude::*;
use rand::Rng as _;
use rand::seq::SliceRandom;

use crate::resources::{
    CoarseViews, Rng, Settings, TrainState, TrainingViews, ViewOrder, ViewSample, views_at,
};

/// Counts the iteration and raises the SH degree by one every `sh_increase_interval` iterations.
pub fn advance_iteration(settings: Res<Settings>, mut state: ResMut<TrainState>) {
    state.iteration += 1;
    let interval = settings.train.sh_increase_interval.max(1);
    if state.iteration % interval == 0 && state.sh_degree < settings.model.sh_degree {
        state.sh_degree += 1;
    }
}

/// Training views whose streamed images are decoded ahead of the iteration that needs them
/// (a no-op for images in memory); a few iterations' worth hides the decoding time.
pub const PREFETCH_VIEWS: usize = 4;

/// Samples a training view uniformly without replacement within an epoch (from the coarse
/// views while coarse-to-fine training is in its coarse stage), and the background colour to
/// render it over: with `train.random_background`, a uniform random colour for views with an
/// alpha matte. With `train.repeat_hard_views`, each epoch also holds a second draw of the
/// views whose loss was highest when last drawn.
pub fn sample_view(
    settings: Res<Settings>,
    views: Res<TrainingViews>,
    coarse: Option<Res<CoarseViews>>,
    state: Res<TrainState>,
    mut order: ResMut<ViewOrder>,
    mut rng: ResMut<Rng>,
    mut sample: ResMut<ViewSample>,
) {
    let dataset = views_at(&views, coarse.as_deref(), state.iteration);
    if order.next >= order.order.len() {
        order.order.clear();
        order.order.extend(0..dataset.train.len());
        let repeats =
            (settings.train.repeat_hard_views * dataset.train.len() as f32).round() as usize;
        if repeats > 0 {
            let hardest = hardest_views(&order.losses, repeats);
            order.order.extend(hardest);
        }
        order.order.shuffle(&mut rng.0);
        order.next = 0;
    }
    let index = order.order[order.next];
    order.next += 1;
    // Streamed images: have the next few of this epoch decoded in the background meanwhile.
    for &ahead in order.order[order.next..].iter().take(PREFETCH_VIEWS) {
        dataset.train[ahead].image.prefetch();
    }
    let view = &dataset.train[index];
    let background = if settings.train.random_background && view.matte.is_some() {
        std::array::from_fn(|_| rng.0.random::<f32>())
    } else {
        settings.train.background
    };
    *sample = ViewSample {
        camera: dataset.cameras[view.camera],
        view: Some(index),
        frame: view.frame,
        time: view.time,
        background,
    };
}

/// The `count` views with the highest recorded loss, hardest first (ties by index); views not
/// drawn yet are not ranked.
pub fn hardest_views(losses: &[Option<f32>], count: usize) -> Vec<usize> {
    let mut ranked: Vec<(usize, f32)> = losses
        .iter()
        .enumerate()
        .filter_map(|(view, loss)| loss.map(|loss| (view, loss)))
        .collect();
    ranked.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    ranked
        .into_iter()
        .take(count)
        .map(|(view, _)| view)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::hardest_views;

    /// The highest losses come first, ties go to the lower index, and views without a loss
    /// are never chosen, even when fewer ranked views exist than asked for.
    #[test]
    fn hardest_views_ranks_recorded_losses() {
        let losses = [Some(0.1), None, Some(0.5), Some(0.2), Some(0.5), None];
        assert_eq!(hardest_views(&losses, 2), vec![2, 4]);
        assert_eq!(hardest_views(&losses, 3), vec![2, 4, 3]);
        assert_eq!(hardest_views(&losses, 10), vec![2, 4, 3, 0]);
        assert!(hardest_views(&losses, 0).is_empty());
    }
}
