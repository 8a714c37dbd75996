//! What a run records while it trains: the figures behind the run report's plots.

use serde::{Deserialize, Serialize};

/// One training iteration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    /// The iteration, from 1.
    pub iteration: u32,
    /// Training loss 0.8·L1 + 0.2·(1 − SSIM) of the iteration's view.
    pub loss: f32,
    /// PSNR of the iteration's render against its training image (dB).
    pub psnr: f32,
    /// Gaussians alive after the iteration.
    pub gaussians: u32,
}

/// One densification step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DensifyRecord {
    /// Iteration of the step.
    pub iteration: u32,
    /// Gaussians cloned.
    pub cloned: u32,
    /// Gaussians split in two.
    pub split: u32,
    /// Gaussians pruned.
    pub pruned: u32,
    /// Gaussians alive after the step.
    pub gaussians: u32,
}

/// Held-out PSNR measured during training.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeldoutRecord {
    /// Iteration after which it was measured.
    pub iteration: u32,
    /// Mean PSNR over the held-out views (dB).
    pub psnr: f32,
}

/// The history of a run, carried through checkpoints so a resumed run reports the whole of it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainingLog {
    /// One record per training iteration, in order.
    pub steps: Vec<StepRecord>,
    /// One record per densification step, in order.
    pub densify: Vec<DensifyRecord>,
    /// Held-out PSNR checks, in order.
    pub heldout: Vec<HeldoutRecord>,
    /// Seconds spent training (evaluation excluded), over every session of the run.
    pub train_seconds: f64,
}

impl TrainingLog {
    /// Drops every record after `iteration` (what a checkpoint of that iteration had not seen).
    pub fn truncate(&mut self, iteration: u32) {
        self.steps.retain(|r| r.iteration <= iteration);
        self.densify.retain(|r| r.iteration <= iteration);
        self.heldout.retain(|r| r.iteration <= iteration);
    }
}
