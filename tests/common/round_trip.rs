//! Shared by the reader tests that write the demo scene in a dataset layout and read it back.

// Each test binary includes this file and uses what it needs.
#![allow(dead_code)]

use std::sync::Arc;

use tadgs::data::{Camera, Dataset};
use tadgs::scene::{DataSource, InitMethod, SceneConfig};
use tadgs::train::Trainer;

/// Largest difference between two cameras' intrinsics and world-to-camera entries (their
/// sizes must be equal).
pub fn camera_difference(a: &Camera, b: &Camera) -> f32 {
    assert_eq!((a.width, a.height), (b.width, b.height));
    let intrinsics = [a.fx - b.fx, a.fy - b.fy, a.cx - b.cx, a.cy - b.cy];
    (a.world_to_camera - b.world_to_camera)
        .to_cols_array()
        .into_iter()
        .chain(intrinsics)
        .fold(0.0, |m, v| m.max(v.abs()))
}

/// `read` has the cameras of `original` (intrinsics and poses to 1e-5), its frame count, and
/// the same training and held-out views (camera, frame, time and identical images).
pub fn assert_same_dataset(original: &Dataset, read: &Dataset) {
    assert_eq!(read.cameras.len(), original.cameras.len());
    for (c, (a, b)) in original.cameras.iter().zip(&read.cameras).enumerate() {
        let diff = camera_difference(a, b);
        assert!(diff < 1e-5, "camera {c} differs by {diff}");
    }
    assert_eq!(read.frame_count, original.frame_count);
    for (name, a, b) in [
        ("train", &original.train, &read.train),
        ("test", &original.test, &read.test),
    ] {
        assert_eq!(a.len(), b.len(), "{name}");
        for view in a {
            let back = b
                .iter()
                .find(|v| v.camera == view.camera && v.frame == view.frame)
                .unwrap_or_else(|| panic!("{name}: camera {} frame {}", view.camera, view.frame));
            assert_eq!(back.time, view.time);
            assert!(back.image == view.image, "{name}: image differs");
        }
    }
}

/// Held-out PSNR of the demo scene's settings trained for `iterations` on `dataset`.
fn trained_psnr(dataset: &Dataset, iterations: u32) -> f32 {
    let mut config = SceneConfig::new(
        "demo",
        DataSource::Synthetic(tadgs::data::synthetic::demo_scene()),
    );
    config.scale_schedule(iterations);
    // The same random initial points for both: the layouts' own clouds are not compared.
    config.init.method = InitMethod::Random;
    let mut trainer = Trainer::new(&config, Arc::new(dataset.clone()));
    for _ in 0..iterations {
        trainer.step();
    }
    trainer
        .heldout_psnr()
        .expect("the dataset has held-out views")
}

/// Trained with the demo's settings from random points, `read` reaches the held-out PSNR of
/// `original` within 0.2 dB (the layout loses nothing training needs: cameras, view order,
/// times, images).
pub fn assert_trains_alike(original: &Dataset, read: &Dataset) {
    let iterations = 300;
    let (a, b) = (
        trained_psnr(original, iterations),
        trained_psnr(read, iterations),
    );
    assert!(
        (a - b).abs() < 0.2,
        "held-out PSNR after {iterations} iterations: {a:.3} dB built in, {b:.3} dB read back"
    );
}
