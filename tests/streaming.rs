//! Views streamed from disk through a bounded cache (`data.cache_mb`) on the real Panoptic
//! capture: the same pixels and the same training as views loaded up front, the cache never
//! holding more than its size, and a file that disappears mid-run stopping training with its
//! name.

mod common;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tadgs::train::Trainer;
use tadgs::data::Dataset;
use tadgs::data::panoptic::{self, PanopticSource};
use tadgs::scene::{DataSource, InitMethod, SceneConfig};

/// The first `frames` timesteps of the capture, at 1/8 resolution (80×45 px).
fn small_source(root: &Path, frames: usize, cache_mb: Option<f64>) -> PanopticSource {
    PanopticSource {
        frames: Some(frames),
        downscale: 8,
        cache_mb,
        ..PanopticSource::new(root.to_string_lossy().into_owned())
    }
}

fn panoptic_root() -> Option<PathBuf> {
    common::data_dir().map(|d| d.join("panoptic_basketball"))
}

/// A short coarse-to-fine run (the coarse stage reads the streamed views through a mapped,
/// downscaled decoder) from random points.
fn scene(source: PanopticSource) -> SceneConfig {
    let mut scene = SceneConfig::new("stream", DataSource::Panoptic(source));
    scene.init.method = InitMethod::Random;
    scene.init.points_per_anchor = 500;
    scene.train.iterations = 40;
    scene.train.coarse_downscale = 2;
    scene.train.coarse_until = 20;
    scene.densify.from_iter = 10;
    scene.densify.interval = 10;
    scene.densify.until_iter = 30;
    scene
}

/// Losses of every iteration and the final held-out PSNR.
fn train(scene: &SceneConfig, dataset: Arc<Dataset>) -> (Vec<f32>, f32) {
    let mut trainer = Trainer::new(scene, dataset);
    let losses = (0..scene.train.iterations)
        .map(|_| {
            trainer.step();
            assert!(trainer.read_failure().is_none());
            trainer.state().loss.total
        })
        .collect();
    (losses, trainer.heldout_psnr().expect("held-out views"))
}

/// Streamed through a cache of 0.1 MB (about nine of the 108 training images), every view
/// has the pixels of the loaded one, and training sees exactly the same images: every
/// iteration's loss and the held-out PSNR are bit for bit those of the loaded run. The cache
/// never held more than its size, and images were both decoded on demand and prefetched.
#[test]
fn streamed_views_train_exactly_like_loaded_views() {
    let Some(root) = panoptic_root() else { return };
    let loaded = Arc::new(panoptic::load(&small_source(&root, 4, None)).unwrap());
    let streamed = Arc::new(panoptic::load(&small_source(&root, 4, Some(0.1))).unwrap());
    assert!(loaded.cache().is_none());
    let cache = streamed.cache().expect("cache_mb streams the views").clone();
    assert_eq!(loaded.train.len(), streamed.train.len());
    let masks: usize = streamed
        .train
        .iter()
        .map(|v| v.foreground.as_ref().map_or(0, Vec::len))
        .sum();
    assert_eq!(streamed.memory_bytes(), masks, "only the masks are held");
    let views = |d: &Dataset| d.train.iter().chain(&d.test).cloned().collect::<Vec<_>>();
    for (a, b) in views(&loaded).iter().zip(&views(&streamed)) {
        assert_eq!((a.camera, a.frame), (b.camera, b.frame));
        assert!(a.image == b.image, "camera {} frame {}", a.camera, a.frame);
    }

    let config = scene(small_source(&root, 4, None));
    let (loaded_losses, loaded_psnr) = train(&config, loaded);
    let (streamed_losses, streamed_psnr) = train(&config, streamed);
    assert_eq!(loaded_losses, streamed_losses);
    assert_eq!(loaded_psnr.to_bits(), streamed_psnr.to_bits());

    let stats = cache.stats();
    assert!(stats.peak_bytes <= 100_000, "{stats:?}");
    assert!(stats.misses > 0 && stats.hits > 0, "{stats:?}");
}

/// A training image deleted after the dataset was read stops the run at the iteration that
/// needs it, before any parameter changes, with an error that names the file.
#[test]
fn deleted_streamed_image_stops_training_and_names_the_file() {
    let Some(root) = panoptic_root() else { return };
    let copy = tempfile::tempdir().unwrap();
    for meta in ["train_meta.json", "test_meta.json"] {
        std::fs::copy(root.join(meta), copy.path().join(meta)).unwrap();
    }
    for entry in std::fs::read_dir(root.join("ims")).unwrap() {
        let camera = entry.unwrap().file_name();
        let folder = copy.path().join("ims").join(&camera);
        std::fs::create_dir_all(&folder).unwrap();
        for frame in ["000000.jpg", "000001.jpg"] {
            std::fs::copy(root.join("ims").join(&camera).join(frame), folder.join(frame)).unwrap();
        }
    }
    let source = PanopticSource {
        foreground_masks: false,
        ..small_source(copy.path(), 2, Some(0.01))
    };
    let dataset = Arc::new(panoptic::load(&source).unwrap());
    let victim = copy.path().join("ims/3/000001.jpg");
    std::fs::remove_file(&victim).unwrap();

    let mut config = scene(source);
    config.train.coarse_downscale = 1;
    let mut trainer = Trainer::new(&config, dataset.clone());
    // Debug output of f32 round-trips exactly, so equal text means equal parameters.
    let parameters = |trainer: &mut Trainer| format!("{:?}", trainer.model().gaussians);
    let before = parameters(&mut trainer);
    let mut stopped = None;
    for _ in 0..(2 * dataset.train.len()) {
        trainer.step();
        if let Some(failure) = trainer.read_failure() {
            stopped = Some(failure.clone());
            break;
        }
    }
    let failure = stopped.expect("an epoch reaches the deleted view");
    assert!(failure.message.contains("000001.jpg"), "{}", failure.message);
    assert!(trainer.fault().is_some(), "the guard stops the optimisation");
    // Nothing changed at the failing iteration, nor after it.
    let at_failure = parameters(&mut trainer);
    trainer.step();
    assert!(at_failure == parameters(&mut trainer), "parameters changed after the failure");
    assert!(before != at_failure, "earlier iterations trained");
}
