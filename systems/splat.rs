//! Projection and rasterization of the deformed Gaussians on the chosen backend.

use bevy_ecs::prelude::*;
use glam::Vec3;
use rayon::prelude::*;

use crate::components::{Deformed, SplatSlot};
use crate::model::project::project;
use crate::raster::Splat;
use crate::resources::{Settings, SplatBuffers, ViewSample};

/// Gathers the deformed Gaussians into slots, projects them (EWA) and blends the image.
pub fn splat(
    settings: Res<Settings>,
    sample: Res<ViewSample>,
    mut buffers: ResMut<SplatBuffers>,
    mut gaussians: Query<(&Deformed, &mut SplatSlot)>,
) {
    let buffers = &mut *buffers;
    let camera = sample.camera;
    buffers.deformed.clear();
    for (slot, (deformed, mut splat_slot)) in gaussians.iter_mut().enumerate() {
        splat_slot.0 = slot as u32;
        buffers.deformed.push(*deformed);
    }
    project_all(&buffers.deformed, &camera, &mut buffers.splats);
    let (width, height) = (camera.width as usize, camera.height as usize);
    buffers.rasterizer.forward(
        &buffers.splats,
        width,
        height,
        settings.train.background,
        &mut buffers.render,
    );
}

/// Projects every deformed Gaussian into `splats` (same order).
pub fn project_all(deformed: &[Deformed], camera: &crate::data::Camera, splats: &mut Vec<Splat>) {
    deformed
        .par_iter()
        .map(|d| project_splat(d, camera))
        .collect_into_vec(splats);
}

/// The splat of one deformed Gaussian; invisible when culled (behind the camera, off screen or
/// with σ(t) below 1/255).
pub fn project_splat(d: &Deformed, camera: &crate::data::Camera) -> Splat {
    match project(
        Vec3::from_array(d.mean),
        d.rotation,
        Vec3::from_array(d.scale),
        d.opacity,
        camera,
    ) {
        Some(p) => Splat {
            mean2d: p.mean2d,
            conic: p.conic,
            depth: p.depth,
            opacity: d.opacity,
            color: d.color,
            extent: p.extent,
            visible: true,
        },
        None => Splat::default(),
    }
}
