//! `train.motion_smoothness`: the regulariser's system adds to each Gaussian's Fourier gradient
//! exactly dL_s/dθ of L_s = λ/|E|·Σ‖v_i − v_j‖² over the k-nearest graph of the positions at
//! the sampled time (checked against finite differences of L_s), and touches no other gradient;
//! likewise for the stretch form, which penalises only the part of v_i − v_j along the edge.

use glam::Vec3;
use tadgs::bench::benchmark_world;
use tadgs::components::{Deformed, Fourier, Grad, Position, Scale, WarpedTime};
use tadgs::model::deform::{MotionBasis, fourier_velocity};
use tadgs::model::smoothness::{NeighbourGraph, Penalty, smoothness_loss};
use tadgs::resources::{DeformEveryGaussian, Settings};
use tadgs::scene::SmoothnessForm;
use tadgs::systems::training_schedule;

const WEIGHT: f32 = 0.5;
const NEIGHBOURS: u32 = 5;

type Gaussian = (&'static Fourier, &'static WarpedTime, &'static Deformed);

/// One iteration on the moving benchmark scene with the regulariser's weight; returns the
/// motion basis and, in query order, each Gaussian's Fourier parameters before the step, its
/// warped time and position at the sampled time, and its Fourier, position and scale
/// gradients.
#[allow(clippy::type_complexity)]
fn one_iteration(
    weight: f32,
    form: SmoothnessForm,
) -> (
    MotionBasis,
    Vec<Fourier>,
    Vec<(f32, Vec3)>,
    Vec<(Grad<Fourier>, Grad<Position>, Grad<Scale>)>,
) {
    let mut world = benchmark_world(600, 64, 36, true);
    // The unregularised world too evaluates the faded Gaussians' positions, which the check
    // builds its graph from.
    world.insert_resource(DeformEveryGaussian);
    {
        let mut settings = world.resource_mut::<Settings>();
        settings.train.motion_smoothness.weight = weight;
        settings.train.motion_smoothness.neighbours = NEIGHBOURS;
        settings.train.motion_smoothness.form = form;
    }
    let before: Vec<Fourier> = world
        .query::<Gaussian>()
        .iter(&world)
        .map(|(f, _, _)| *f)
        .collect();
    training_schedule().run(&mut world);
    let at_time = world
        .query::<Gaussian>()
        .iter(&world)
        .map(|(_, w, d)| (w.dtw, Vec3::from_array(d.mean)))
        .collect();
    let grads = world
        .query::<(&Grad<Fourier>, &Grad<Position>, &Grad<Scale>)>()
        .iter(&world)
        .map(|(f, p, s)| (*f, *p, *s))
        .collect();
    let basis = world.resource::<Settings>().motion_basis();
    (basis, before, at_time, grads)
}

#[test]
fn regulariser_adds_the_finite_difference_gradient_of_its_loss_to_the_motion_only() {
    check_form(SmoothnessForm::Velocity);
}

#[test]
fn stretch_form_adds_the_finite_difference_gradient_of_its_loss_to_the_motion_only() {
    check_form(SmoothnessForm::Stretch);
}

fn check_form(form: SmoothnessForm) {
    let (basis, fourier, at_time, plain) = one_iteration(0.0, form);
    let (_, fourier_again, at_time_again, regularised) = one_iteration(WEIGHT, form);
    assert_eq!(fourier, fourier_again, "the two worlds start alike");
    assert_eq!(at_time, at_time_again, "and are evaluated at the same time");

    let velocity = |f: &Fourier, dtw: f32| fourier_velocity(&f.cos, &f.sin, &f.phase, basis, dtw);
    let positions: Vec<Vec3> = at_time.iter().map(|(_, p)| *p).collect();
    let graph = NeighbourGraph::k_nearest(&positions, NEIGHBOURS as usize);
    let penalty = match form {
        SmoothnessForm::Velocity => Penalty::Velocity,
        SmoothnessForm::Stretch => Penalty::Stretch(&positions),
    };
    let velocities: Vec<Vec3> = fourier
        .iter()
        .zip(&at_time)
        .map(|(f, (dtw, _))| velocity(f, *dtw))
        .collect();
    let loss = smoothness_loss(&velocities, &graph, WEIGHT, penalty);
    assert!(loss > 0.0, "the moving Gaussians' velocities differ");

    let mut checked = 0;
    for i in (0..fourier.len()).step_by(37) {
        if graph.neighbours(i).is_empty() {
            continue;
        }
        let (dtw, _) = at_time[i];
        // Position and scale gradients: the photometric ones, untouched.
        assert_eq!(
            plain[i].1, regularised[i].1,
            "position gradient of Gaussian {i}"
        );
        assert_eq!(
            plain[i].2, regularised[i].2,
            "scale gradient of Gaussian {i}"
        );
        let added = |g: &Grad<Fourier>, h: &Grad<Fourier>, f: usize, k: usize| {
            g.0.cos[f][k] - h.0.cos[f][k]
        };
        for (f, k) in [(0, 0), (1, 2), (3, 1)] {
            let h = 1e-2;
            let loss_at = |x: f32| {
                let mut v = velocities.clone();
                let mut p = fourier[i];
                p.cos[f][k] = x;
                v[i] = velocity(&p, dtw);
                smoothness_loss(&v, &graph, WEIGHT, penalty) as f64
            };
            let x = fourier[i].cos[f][k];
            let fd = (loss_at(x + h) - loss_at(x - h)) / (2.0 * h as f64);
            let analytic = added(&regularised[i].0, &plain[i].0, f, k) as f64;
            // f32 sums of ~|E| terms: compare to 1e-3 of the loss's own scale per unit change.
            let tolerance = 1e-3 * fd.abs().max(analytic.abs()) + 1e-4 * loss as f64;
            assert!(
                (analytic - fd).abs() <= tolerance,
                "Gaussian {i}, cos[{f}][{k}]: system added {analytic}, finite difference {fd}"
            );
        }
        checked += 1;
    }
    assert!(checked > 5, "only {checked} Gaussians had neighbours");
}
