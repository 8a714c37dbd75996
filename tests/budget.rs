//! Resource bounds: the memory estimate logged before training, the error for a run whose
//! initial Gaussians cannot fit, and the population cap with its log line.

mod tiny;

use std::io::Write;
use std::sync::{Arc, Mutex, Once};

use tadgs::scene::SceneConfig;
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
