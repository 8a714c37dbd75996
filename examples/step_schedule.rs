//! Step the tadgs training schedule by hand in a plain bevy_ecs `World`.
//!
//! Loads the demo scene from its RON file (shrunk with overrides so this runs in seconds),
//! inserts the tadgs resources, spawns the initial Gaussians, runs the schedule N times and
//! reads components back: the loss, the Gaussian count and the opacity of the population.
//!
//! ```text
//! cargo run --release --example step_schedule -- 200
//! ```

mod common;

use anyhow::Result;
use tadgs::components::{Opacity, Position};
use tadgs::model::deform::sigmoid;
use tadgs::resources::TrainState;
use tadgs::systems::training_schedule;

/// What a run of the schedule did.
#[derive(Debug)]
struct Outcome {
    spawned: usize,
    alive: usize,
    iterations: u32,
    /// Mean training loss of the first and the last 10 iterations.
    early_loss: f32,
    late_loss: f32,
    mean_opacity: f32,
}

fn run(iterations: u32) -> Result<Outcome> {
    let (_, mut world, spawned) = common::small_demo_world(&[
        "densify.from_iter=50",
        "densify.interval=50",
        "densify.until_iter=150",
        "densify.opacity_reset_interval=0",
    ])?;
    let mut schedule = training_schedule();

    let mut losses = Vec::with_capacity(iterations as usize);
    for _ in 0..iterations {
        schedule.run(&mut world);
        losses.push(world.resource::<TrainState>().loss.total);
    }

    let opacities: Vec<f32> = world
        .query::<&Opacity>()
        .iter(&world)
        .map(|o| sigmoid(o.logit))
        .collect();
    let mean = |values: &[f32]| values.iter().sum::<f32>() / values.len().max(1) as f32;
    let window = losses.len().min(10);
    Ok(Outcome {
        spawned,
        alive: world.query::<&Position>().iter(&world).len(),
        iterations: world.resource::<TrainState>().iteration,
        early_loss: mean(&losses[..window]),
        late_loss: mean(&losses[losses.len() - window..]),
        mean_opacity: mean(&opacities),
    })
}

fn main() -> Result<()> {
    let iterations = std::env::args()
        .nth(1)
        .map(|a| a.parse())
        .transpose()?
        .unwrap_or(200);
    let o = run(iterations)?;
    println!("{} iterations", o.iterations);
    println!("Gaussians: {} spawned, {} alive", o.spawned, o.alive);
    println!(
        "loss: {:.4} (first 10) → {:.4} (last 10)",
        o.early_loss, o.late_loss
    );
    println!("mean opacity: {:.3}", o.mean_opacity);
    Ok(())
}

#[cfg(test)]
mod tests {
    /// Stepping the schedule 200 times by hand trains: the loss of the last ten iterations is
    /// below 70 % of the first ten, the iteration counter advanced by exactly the number of
    /// runs, and densification changed the population.
    #[test]
    fn stepping_by_hand_trains_the_population() {
        let outcome = super::run(200).expect("the example runs");
        assert_eq!(outcome.iterations, 200);
        assert!(outcome.late_loss < 0.7 * outcome.early_loss, "{outcome:?}");
        assert_ne!(outcome.alive, outcome.spawned, "{outcome:?}");
        assert!(outcome.mean_opacity > 0.0 && outcome.mean_opacity < 1.0);
    }
}
