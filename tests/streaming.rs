//! Views streamed from disk through a bounded cache (`data.cache_mb`) on the real Panoptic
//! capture: the same pixels and the same training as views loaded up front, the cache never
//! holding more than its size, and a file that disappears mid-run stopping training with its
//! name.

mod common;
#[path = "common/llff.rs"]
mod llff;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tadgs::data::Dataset;
use tadgs::data::n3dv::{self, N3dvSource};
use tadgs::data::panoptic::{self, PanopticSource};
use tadgs::scene::{DataSource, InitMethod, SceneConfig};
use tadgs::train::Trainer;

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
    let cache = streamed
        .cache()
        .expect("cache_mb streams the views")
        .clone();
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
            std::fs::copy(
                root.join("ims").join(&camera).join(frame),
                folder.join(frame),
            )
            .unwrap();
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
    assert!(
        failure.message.contains("000001.jpg"),
        "{}",
        failure.message
    );
    assert!(
        trainer.fault().is_some(),
        "the guard stops the optimisation"
    );
    // Nothing changed at the failing iteration, nor after it.
    let at_failure = parameters(&mut trainer);
    trainer.step();
    assert!(
        at_failure == parameters(&mut trainer),
        "parameters changed after the failure"
    );
    assert!(before != at_failure, "earlier iterations trained");
}

/// Peak resident memory of this process so far (`VmHWM`), in bytes.
fn peak_resident_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|line| line.strip_prefix("VmHWM:"))
        .and_then(|kb| kb.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}

/// Writes an N3DV scene of `cameras` × `frames` JPEG frames of `width × height` in frame
/// folders, the cameras on a circle around the origin looking at it. Each frame is smooth
/// colour ramps with blocks that move with the frame, so the files stay small.
fn write_n3dv_sized(root: &Path, cameras: usize, frames: usize, (width, height): (u32, u32)) {
    use glam::DVec3;
    use rayon::prelude::*;
    let focal = 0.8 * f64::from(width);
    let rows: Vec<[f64; 17]> = (0..cameras)
        .map(|c| {
            let angle = 0.8 * (c as f64 / cameras as f64 - 0.5);
            let centre = DVec3::new(4.0 * angle.sin(), 0.0, -4.0 * angle.cos());
            let forward = -centre.normalize();
            let right = forward.cross(DVec3::Y).normalize();
            let down = forward.cross(right);
            llff::llff_row(
                down.into(),
                right.into(),
                (-forward).into(),
                centre.into(),
                [f64::from(height), f64::from(width), focal],
            )
        })
        .collect();
    llff::write_poses(&root.join("poses_bounds.npy"), &rows);
    let jobs: Vec<(usize, usize)> = (0..cameras)
        .flat_map(|c| (0..frames).map(move |f| (c, f)))
        .collect();
    for c in 0..cameras {
        std::fs::create_dir_all(root.join(format!("frames/cam{c:02}"))).unwrap();
    }
    jobs.par_iter().for_each(|&(c, f)| {
        let image = image::RgbImage::from_fn(width, height, |x, y| {
            let block = ((x + 4 * f as u32) / 64 + y / 64 + c as u32) % 2;
            image::Rgb([
                (x * 255 / width) as u8,
                (y * 255 / height) as u8,
                60 + 140 * block as u8,
            ])
        });
        let file =
            std::fs::File::create(root.join(format!("frames/cam{c:02}/{f:06}.jpg"))).unwrap();
        let mut writer = std::io::BufWriter::new(file);
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut writer, 90)
            .encode_image(&image)
            .unwrap();
    });
}

/// An N3DV-sized capture, 20 cameras × 300 frames at 1352×1014 (24.7 GB decoded), trains
/// streamed through a 1 GB cache (about 240 frames, so it fills and evicts within the run)
/// with at most 8 GB resident at any time, the background thread decoding the frames as fast
/// as training consumes them (at most one request in ten waits for the disk). Prints the figures for the
/// README. Writes about 1 GB of JPEGs and trains 300 iterations at full size: run by hand with
/// `cargo test --release --test streaming -- --ignored --nocapture`.
#[test]
#[ignore = "writes an N3DV-sized capture (6 000 JPEGs at 1352×1014) and trains on it: minutes"]
fn n3dv_sized_capture_trains_streamed_within_8_gb() {
    const GB: f64 = 1e9;
    let dir = tempfile::tempdir().unwrap();
    let start = std::time::Instant::now();
    write_n3dv_sized(dir.path(), 20, 300, (1352, 1014));
    let written = start.elapsed().as_secs_f64();
    let on_disk: u64 = walk_bytes(dir.path());

    let source = N3dvSource {
        downscale: 1,
        cache_mb: Some(1000.0),
        ..N3dvSource::new(dir.path().to_string_lossy())
    };
    let start = std::time::Instant::now();
    let dataset = Arc::new(n3dv::load(&source).unwrap());
    let loaded = start.elapsed().as_secs_f64();
    let views = dataset.train.len() + dataset.test.len();
    let decoded: u64 = dataset
        .train
        .iter()
        .chain(&dataset.test)
        .map(|v| 3 * u64::from(v.image.width()) * u64::from(v.image.height()))
        .sum();
    assert_eq!(views, 6000);

    let mut scene = SceneConfig::new("n3dv-sized", DataSource::N3dv(source));
    scene.init.method = InitMethod::Random;
    scene.init.points_per_anchor = 2000;
    scene.train.iterations = 300;
    scene.densify.from_iter = 100;
    scene.densify.until_iter = 250;
    let mut trainer = Trainer::new(&scene, dataset.clone());
    let start = std::time::Instant::now();
    for _ in 0..scene.train.iterations {
        trainer.step();
        assert!(trainer.read_failure().is_none());
        assert!(trainer.fault().is_none());
    }
    let rate = f64::from(scene.train.iterations) / start.elapsed().as_secs_f64();
    let stats = dataset.cache().unwrap().stats();
    let peak = peak_resident_bytes();
    println!(
        "N3DV-sized capture: {views} views, {:.1} GB decoded, {:.2} GB of JPEG written in {written:.0} s; \
         read (headers) in {loaded:.1} s; {:.2} it/s at 1352×1014 with {} Gaussians; cache {stats:?}; \
         peak resident {:.2} GB",
        decoded as f64 / GB,
        on_disk as f64 / GB,
        rate,
        trainer.gaussian_count(),
        peak as f64 / GB,
    );
    assert!(stats.peak_bytes as f64 <= 1000e6, "{stats:?}");
    assert!(stats.misses <= 30, "the prefetcher fell behind: {stats:?}");
    assert!(
        peak as f64 <= 8.0 * GB,
        "peak resident {:.2} GB",
        peak as f64 / GB
    );
}

fn walk_bytes(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|entry| {
            let entry = entry.unwrap();
            let meta = entry.metadata().unwrap();
            if meta.is_dir() {
                walk_bytes(&entry.path())
            } else {
                meta.len()
            }
        })
        .sum()
}
