//! Projection and rasterization of the deformed Gaussians on the chosen backend.

use bevy_ecs::prelude::*;
use glam::Vec3;
use rayon::prelude::*;

use crate::components::{Deformed, SplatSlot};
use crate::gpu::GpuRasterizer;
use crate::model::project::project_beyond;
use crate::raster::Splat;
use crate::resources::{Settings, SplatBuffers, ViewSample};

/// Projects the deformed Gaussians (EWA) into slots and blends the image, on the
/// GPU when there is a [`GpuRasterizer`] resource.
pub fn splat(
    settings: Res<Settings>,
    sample: Res<ViewSample>,
    mut buffers: ResMut<SplatBuffers>,
    gpu: Option<ResMut<GpuRasterizer>>,
    mut gaussians: Query<(&Deformed, &mut SplatSlot)>,
) -> Result {
    let buffers = &mut *buffers;
    let camera = sample.camera;
    let near_plane = settings.train.near_plane;
    buffers.splats.clear();
    // Table by table (one, unless some Gaussians lack an optional group): the column's
    // projection and the slot numbers each in one parallel pass, rather than one entity at a
    // time. The slots number the tables' rows in this order.
    let tables = gaussians
        .contiguous_iter_mut()
        .expect("the splatting stage's components are stored in tables, so the query is dense");
    for (deformed, mut slots) in tables {
        let first = buffers.splats.len();
        extend_projected(deformed, &camera, near_plane, &mut buffers.splats);
        slots[..]
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, slot)| slot.0 = (first + i) as u32);
    }
    let (width, height) = (camera.width as usize, camera.height as usize);
    let background = sample.background;
    match gpu {
        Some(mut gpu) => gpu.forward(
            &buffers.splats,
            width,
            height,
            background,
            &mut buffers.render,
        )?,
        None => buffers.rasterizer.forward(
            &buffers.splats,
            width,
            height,
            background,
            &mut buffers.render,
        ),
    }
    Ok(())
}

/// A copy of the deformed Gaussians in slot order, as the last run of [`splat`] numbered them
/// (for tools and tests that work on the slot-indexed arrays).
pub fn deformed_by_slot(world: &mut World) -> Vec<Deformed> {
    let slots = world.resource::<SplatBuffers>().splats.len();
    let mut out = vec![Deformed::default(); slots];
    for (d, slot) in world.query::<(&Deformed, &SplatSlot)>().iter(world) {
        out[slot.0 as usize] = *d;
    }
    out
}

/// Projects every deformed Gaussian into `splats` (same order); those nearer than `near_plane`
/// are invisible.
pub fn project_all(
    deformed: &[Deformed],
    camera: &crate::data::Camera,
    near_plane: f32,
    splats: &mut Vec<Splat>,
) {
    splats.clear();
    extend_projected(deformed, camera, near_plane, splats);
}

/// Appends the splats of `deformed` (same order) to `splats`, in parallel.
fn extend_projected(
    deformed: &[Deformed],
    camera: &crate::data::Camera,
    near_plane: f32,
    splats: &mut Vec<Splat>,
) {
    splats.par_extend(
        deformed
            .par_iter()
            .map(|d| project_splat(d, camera, near_plane)),
    );
}

/// The splat of one deformed Gaussian; invisible when culled (nearer than `near_plane`, off
/// screen or with σ(t) below 1/255).
pub fn project_splat(d: &Deformed, camera: &crate::data::Camera, near_plane: f32) -> Splat {
    match project_beyond(
        Vec3::from_array(d.mean),
        d.rotation,
        Vec3::from_array(d.scale),
        d.opacity,
        camera,
        near_plane,
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
