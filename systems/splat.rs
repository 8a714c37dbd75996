//! Projection and rasterization of the deformed Gaussians on the chosen backend.

use bevy_ecs::prelude::*;
use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::components::{Deformed, SplatSlot};
use crate::gpu::GpuRasterizer;
use crate::model::project::project_beyond;
use crate::model::project_lanes::{GaussianLanes, LANES, ProjectedLanes, ViewTerms, project_lanes};
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
    // Table by table (one, unless some Gaussians lack an optional group): the column's
    // projection and the slot numbers each in one parallel pass, rather than one entity at a
    // time. The slots number the tables' rows in this order.
    let tables = gaussians
        .contiguous_iter_mut()
        .expect("the splatting stage's components are stored in tables, so the query is dense");
    // The splat buffer keeps its length from one iteration to the next, so it is written
    // once per splat (not cleared, then filled).
    let mut first = 0;
    for (deformed, mut slots) in tables {
        let end = first + deformed.len();
        if buffers.splats.len() < end {
            buffers.splats.resize(end, Splat::default());
        }
        project_into(
            deformed,
            &camera,
            near_plane,
            &mut buffers.splats[first..end],
        );
        slots[..]
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, slot)| slot.0 = (first + i) as u32);
        first = end;
    }
    buffers.splats.truncate(first);
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
    splats.resize(deformed.len(), Splat::default());
    project_into(deformed, camera, near_plane, splats);
}

/// Projects `deformed` into `splats` (same length and order) in parallel, eight Gaussians at
/// a time ([`project_lanes`]: the same splats as [`project_splat`] one at a time).
fn project_into(
    deformed: &[Deformed],
    camera: &crate::data::Camera,
    near_plane: f32,
    splats: &mut [Splat],
) {
    /// Gaussians per parallel task (a multiple of [`LANES`]).
    const CHUNK: usize = 512 * LANES;
    let terms = ViewTerms::new(camera, near_plane);
    splats
        .par_chunks_mut(CHUNK)
        .zip(deformed.par_chunks(CHUNK))
        .for_each(|(out, deformed)| project_chunk(deformed, &terms, out));
}

crate::raster::simd_kernel! {
    /// Projects `deformed` into `out` (same length), eight at a time; a last group of fewer
    /// fills its other lanes with transparent Gaussians, which it does not write.
    fn project_chunk(deformed: &[Deformed], terms: &ViewTerms, out: &mut [Splat]) {
        let mut lanes = GaussianLanes::default();
        let mut projected = ProjectedLanes::default();
        for (group, out) in deformed.chunks(LANES).zip(out.chunks_mut(LANES)) {
            if group.len() < LANES {
                lanes = GaussianLanes::default();
            }
            gather_lanes(group, &mut lanes);
            project_lanes(&lanes, terms, &mut projected);
            scatter_lanes(&projected, group, out);
        }
    }
}

/// Copies the projection's inputs of up to [`LANES`] Gaussians into lanes. Out of line: the
/// kernel then loads each lane array as one vector; inlined, the compiler would forward the
/// scalars into the arithmetic and leave it scalar.
#[inline(never)]
pub(crate) fn gather_lanes(group: &[Deformed], lanes: &mut GaussianLanes) {
    for (i, d) in group.iter().enumerate() {
        for k in 0..3 {
            lanes.mean[k][i] = d.mean[k];
            lanes.scale[k][i] = d.scale[k];
        }
        for k in 0..4 {
            lanes.quat[k][i] = d.rotation[k];
        }
        lanes.opacity[i] = d.opacity;
    }
}

/// Writes the splats of up to [`LANES`] projected Gaussians (out of line, as
/// [`gather_lanes`], so that the kernel stores each lane array as one vector).
#[inline(never)]
fn scatter_lanes(p: &ProjectedLanes, group: &[Deformed], out: &mut [Splat]) {
    for (i, (splat, d)) in out.iter_mut().zip(group).enumerate() {
        *splat = if p.kept[i] {
            Splat {
                mean2d: Vec2::new(p.mean2d[0][i], p.mean2d[1][i]),
                conic: [p.conic[0][i], p.conic[1][i], p.conic[2][i]],
                depth: p.depth[i],
                opacity: d.opacity,
                color: d.color,
                extent: Vec2::new(p.extent[0][i], p.extent[1][i]),
                visible: true,
            }
        } else {
            Splat::default()
        };
    }
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
