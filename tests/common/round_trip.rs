//! Shared by the reader tests that write the demo scene in a dataset layout and read it back.

// Each test binary includes this file and uses what it needs.
#![allow(dead_code)]

use tadgs::data::{Camera, Dataset};

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
