//! Resource bounds: the memory estimate logged before training, the error for a run whose
//! initial Gaussians cannot fit, and the population cap with its log line.

mod tiny;

use std::io::Write;
use std::sync::{Arc, Mutex, Once};

use tadgs::scene::{CapPolicy, SceneConfig};
use tadgs::train::{InitError, Trainer};

/// Everything logged in this test binary (one global subscriber: the systems log from
/// worker threads).
static LOG: Mutex<Vec<u8>> = Mutex::new(Vec::new());

struct LogWriter;

impl Write for LogWriter {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        LOG.lock().unwrap().extend_from_slice(bytes);
        Ok(bytes.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

fn capture_logs() {
    static INIT: Once = Once::new();
    INIT.call_once(|| {
        tracing_subscriber::fmt()
            .with_writer(|| LogWriter)
            .with_max_level(tracing::Level::INFO)
            .with_ansi(false)
            .init();
    });
}

fn logged() -> String {
    String::from_utf8_lossy(&LOG.lock().unwrap()).into_owned()
}

fn tiny_scene() -> (SceneConfig, Arc<tadgs::data::Dataset>) {
    tiny::tiny_demo(32, 24, 60)
}

/// Densification stops growing at `densify.max_gaussians`: with every Gaussian qualifying,
/// the population never exceeds the cap, and a log line says the cap was reached. The
/// memory estimate is logged when the trainer is built.
#[test]
fn population_stops_at_the_cap_with_a_log_line() {
    capture_logs();
    let (mut config, dataset) = tiny_scene();
    config.densify.max_gaussians = 200;
    config.densify.grad_threshold = 1e-12; // every Gaussian seen qualifies
    config.densify.from_iter = 1;
    config.densify.interval = 2;
    let mut trainer = Trainer::new(&config, dataset);
    assert_eq!(trainer.gaussian_count(), 180);
    assert!(logged().contains("memory estimate:"), "{}", logged());
    for _ in 0..8 {
        trainer.step();
        assert!(
            trainer.gaussian_count() <= 200,
            "{}",
            trainer.gaussian_count()
        );
    }
    assert!(trainer.gaussian_count() > 180, "densification ran");
    let log = logged();
    assert!(
        log.contains("population cap densify.max_gaussians = 200 reached"),
        "{log}"
    );
}

/// A run whose initial Gaussians could never fit in memory is refused when the trainer is
/// built, before anything is allocated for them, with an error naming what to lower.
#[test]
fn initial_gaussians_beyond_memory_are_an_error() {
    if tadgs::budget::available_memory().is_none() {
        eprintln!("skipping: no /proc/meminfo on this system, so no memory check to test");
        return;
    }
    let (mut config, dataset) = tiny_scene();
    config.init.points_per_anchor = 1 << 50;
    match Trainer::try_new(&config, dataset) {
        Err(InitError::Memory(error)) => {
            let message = error.to_string();
            assert!(message.contains("init.points_per_anchor"), "{message}");
            assert!(message.contains("32×24"), "{message}");
        }
        Err(other) => panic!("expected a memory error, got {other}"),
        Ok(_) => panic!("a run of 2^50 Gaussians per anchor was accepted"),
    }
}

/// The Gaussians of a 180-Gaussian world, each marked by a distinct DC colour, after one
/// densification step under `policy` with room for 10 more: Gaussian i qualifies with
/// ḡ / threshold = 1 + i / 10 when i is even; every third Gaussian is faint (σ^s ≈ 0.02).
/// Returns how many entities carry each mark afterwards (2 = cloned or split, 0 = pruned).
fn marks_after_one_step_at_the_cap(policy: CapPolicy) -> (Vec<usize>, usize) {
    use bevy_ecs::system::RunSystemOnce;
    use bevy_ecs::world::World;
    use tadgs::components::{Color, GradAccum, Opacity};
    use tadgs::resources::Settings;
    use tadgs::systems::densify::densify_and_prune;
    use tadgs::train::{insert_resources, spawn_initial_gaussians};

    let (mut config, dataset) = tiny_scene();
    config.densify.tat = false;
    config.densify.prune_opacity = 0.001;
    config.densify.at_cap = policy;
    let threshold = config.densify.grad_threshold;
    let mut world = World::new();
    insert_resources(&mut world, &config, dataset).expect("CPU backend");
    spawn_initial_gaussians(&mut world, &config).expect("random points initialise");
    let count = world.query::<&Color>().iter(&world).count();
    world.resource_mut::<Settings>().densify.max_gaussians = count + 10;
    let mut query = world.query::<(&mut Color, &mut Opacity, &mut GradAccum)>();
    for (i, (mut color, mut opacity, mut accum)) in query.iter_mut(&mut world).enumerate() {
        color.dc = [i as f32, 0.0, 0.0];
        opacity.logit = if i % 3 == 0 { -4.0 } else { 0.0 };
        let strength = if i % 2 == 0 {
            1.0 + i as f32 / 10.0
        } else {
            0.5
        };
        *accum = GradAccum {
            weighted_grad: strength * threshold,
            weight: 1.0,
            lifespan_sum: 1.0,
            count: 1,
            max_radius: 1.0,
            weighted_offset: 0.0,
        };
    }
    world
        .run_system_once(densify_and_prune)
        .expect("densification runs");
    let mut marks = vec![0; count];
    for color in world.query::<&Color>().iter(&world) {
        marks[color.dc[0] as usize] += 1;
    }
    (marks, count)
}

/// `Strongest` gives the room under the cap to the ten qualifying Gaussians with the largest
/// ḡ / threshold; `Replace` also prunes faint non-qualifying Gaussians, faintest first, and
/// gives their places to the next strongest; the population ends at the cap either way.
#[test]
fn at_the_cap_the_strongest_are_densified_and_faint_ones_make_room() {
    let (marks, count) = marks_after_one_step_at_the_cap(CapPolicy::Strongest);
    let densified: Vec<usize> = (0..count).filter(|&i| marks[i] == 2).collect();
    let strongest: Vec<usize> = (0..count).filter(|i| i % 2 == 0).rev().take(10).collect();
    assert_eq!(densified, strongest.into_iter().rev().collect::<Vec<_>>());
    assert_eq!(marks.iter().sum::<usize>(), count + 10);
    assert!(marks.iter().all(|&m| m >= 1), "nothing pruned");

    let (marks, count) = marks_after_one_step_at_the_cap(CapPolicy::Replace { max_opacity: 0.05 });
    // Faint and not qualifying: odd multiples of 3. Qualifying: the 90 even ones.
    let faint = (0..count).filter(|i| i % 3 == 0 && i % 2 == 1).count();
    let pruned: Vec<usize> = (0..count).filter(|&i| marks[i] == 0).collect();
    assert_eq!(
        pruned.len(),
        faint,
        "every faint one gives up its place (80 left out)"
    );
    assert!(pruned.iter().all(|i| i % 3 == 0 && i % 2 == 1));
    let densified = (0..count).filter(|&i| marks[i] == 2).count();
    assert_eq!(densified, 10 + faint);
    assert!(
        (0..count)
            .filter(|&i| marks[i] == 2)
            .all(|i| i % 2 == 0 && i >= count - 2 * (10 + faint))
    );
    assert_eq!(marks.iter().sum::<usize>(), count + 10);
}
