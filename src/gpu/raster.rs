//! The splat rasterizer on the GPU: the same forward and backward blending as
//! [`crate::raster::Rasterizer`], with the per-pixel loops as compute passes.

use bytemuck::{Pod, Zeroable};

use super::kernel::dispatch_grid;
use super::{FLOAT_ATOMIC_FEATURES, GpuContext, GpuError, GrowBuffer};
use crate::raster::{RenderOutput, Splat, SplatGrad, TileBins, min_power};

/// A splat as the shaders read it (`Splat` in `shaders/raster_common.wgsl`).
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
#[repr(C)]
struct GpuSplat {
    mean: [f32; 2],
    extent: [f32; 2],
    /// conic a, b, c and the exponent below which alpha < 1/255.
    conic: [f32; 4],
    /// colour and opacity.
    color: [f32; 4],
}

/// `Params` in `shaders/raster_common.wgsl`.
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
#[repr(C)]
struct Params {
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    background: [f32; 4],
}

/// Gradient fields per entry and per splat: mean (2), conic (3), opacity, colour (3).
const FIELDS: usize = 9;
/// Invocations per workgroup of the per-splat reduction.
const REDUCE_GROUP: u32 = 256;
/// Most workgroups per dispatch dimension.
const MAX_GROUPS: u32 = 65_535;

const FORWARD_WGSL: &str = concat!(
    include_str!("../../shaders/raster_common.wgsl"),
    include_str!("../../shaders/raster_lanes_plain.wgsl"),
    include_str!("../../shaders/raster_forward.wgsl")
);
const FORWARD_SUBGROUP_WGSL: &str = concat!(
    include_str!("../../shaders/raster_common.wgsl"),
    include_str!("../../shaders/raster_lanes_subgroup.wgsl"),
    include_str!("../../shaders/raster_forward.wgsl")
);
const BACKWARD_TILES_WGSL: &str = concat!(
    include_str!("../../shaders/raster_common.wgsl"),
    include_str!("../../shaders/raster_lanes_plain.wgsl"),
    include_str!("../../shaders/raster_backward.wgsl"),
    include_str!("../../shaders/raster_backward_tiles.wgsl")
);
const BACKWARD_ATOMIC_WGSL: &str = concat!(
    include_str!("../../shaders/raster_common.wgsl"),
    include_str!("../../shaders/raster_lanes_subgroup.wgsl"),
    include_str!("../../shaders/raster_backward.wgsl"),
    include_str!("../../shaders/raster_backward_atomic.wgsl")
);
const REDUCE_WGSL: &str = include_str!("../../shaders/raster_reduce.wgsl");
/// The line of `shaders/raster_common.wgsl` that sets the blending kernels' pixels per
/// invocation (see [`GpuRasterizer::with_pixel_rows`]).
const PIXEL_ROWS_LINE: &str = "const PIXEL_ROWS: u32 = 8u;";

/// `source` with its blending kernels set to `rows` pixels per invocation.
fn with_rows(source: &str, rows: u32) -> String {
    assert!(
        source.contains(PIXEL_ROWS_LINE),
        "raster_common.wgsl no longer sets PIXEL_ROWS as {PIXEL_ROWS_LINE:?}"
    );
    source.replace(
        PIXEL_ROWS_LINE,
        &format!("const PIXEL_ROWS: u32 = {rows}u;"),
    )
}

/// GPU rasterizer state: device, pipelines and buffers reused across iterations. As a
/// resource it makes the splat and backward stages blend on the GPU.
#[derive(bevy_ecs::resource::Resource)]
pub struct GpuRasterizer {
    gpu: GpuContext,
    forward: wgpu::ComputePipeline,
    backward: wgpu::ComputePipeline,
    /// Whether `backward` adds into the splat gradients with float atomics (else it writes
    /// per-entry partial sums that `reduce` adds up).
    atomics: bool,
    /// Pixels of a tile column each invocation of the blending kernels blends.
    pixel_rows: u32,
    reduce: wgpu::ComputePipeline,
    /// Tile binning and depth sort (on the CPU).
    bins: TileBins,
    params: GrowBuffer,
    splats: GrowBuffer,
    sorted_splats: GrowBuffer,
    tile_offsets: GrowBuffer,
    splat_offsets: GrowBuffer,
    sorted_position: GrowBuffer,
    rgba: GrowBuffer,
    final_transmittance: GrowBuffer,
    contributors: GrowBuffer,
    d_color: GrowBuffer,
    entry_grads: GrowBuffer,
    splat_grads: GrowBuffer,
    staging: GrowBuffer,
    host_splats: Vec<GpuSplat>,
    host_rgba: Vec<[f32; 4]>,
    host_grads: Vec<[f32; FIELDS]>,
    /// Tiles across and down of the last forward pass.
    tiles: (u32, u32),
    /// (tile, splat) pairs and splats of the last forward pass.
    entries: usize,
    count: usize,
}

impl GpuRasterizer {
    /// Opens the default GPU (see [`GpuContext::new`]) and builds the pipelines, with the
    /// float-atomic backward where the adapter offers SHADER_FLOAT32_ATOMIC and SUBGROUP.
    pub fn new() -> Result<Self, GpuError> {
        Ok(Self::with_context(GpuContext::new(true)?))
    }

    /// [`GpuRasterizer::new`] with the portable backward (per-tile partial sums and a
    /// reduction) whatever the adapter offers.
    pub fn portable() -> Result<Self, GpuError> {
        Ok(Self::with_context(GpuContext::new(false)?))
    }

    /// Builds the pipelines on an open device; the backward uses float atomics when the
    /// device was opened with SHADER_FLOAT32_ATOMIC and SUBGROUP. The blending kernels take 8
    /// pixels per invocation on a software adapter (lavapipe runs every read of workgroup
    /// memory and every subgroup operation as a loop over its SIMD lanes, so reading a splat
    /// once for eight pixels took 30 % less time in the forward and 25 % less in the backward
    /// than for four), one on a hardware GPU (the layout of the reference GPU rasterizers,
    /// which keeps 256 invocations per tile to hide memory latency).
    pub fn with_context(gpu: GpuContext) -> Self {
        let rows = if gpu.is_software() { 8 } else { 1 };
        Self::with_pixel_rows(gpu, rows)
    }

    /// [`GpuRasterizer::with_context`] with the blending kernels set to `rows` pixels of a
    /// tile column per invocation (1, 2, 4, 8 or 16), whatever the adapter.
    pub fn with_pixel_rows(gpu: GpuContext, rows: u32) -> Self {
        assert!(
            matches!(rows, 1 | 2 | 4 | 8 | 16),
            "pixel rows per invocation must divide the 16 rows of a tile, not {rows}"
        );
        let device = &gpu.device;
        let pipeline = |label: &str, source: &str, entry: &str| {
            let [pipeline] = super::kernel::pipelines(device, label, source, [entry]);
            pipeline
        };
        let blending = |label: &str, source: &str, entry: &str| {
            pipeline(label, &with_rows(source, rows), entry)
        };
        // The fast backward's features include SUBGROUP, which the forward uses too.
        let atomics = device.features().contains(FLOAT_ATOMIC_FEATURES);
        let (forward, backward) = if atomics {
            (
                blending("raster_forward", FORWARD_SUBGROUP_WGSL, "forward"),
                blending("raster_backward_atomic", BACKWARD_ATOMIC_WGSL, "backward"),
            )
        } else {
            (
                blending("raster_forward", FORWARD_WGSL, "forward"),
                blending("raster_backward_tiles", BACKWARD_TILES_WGSL, "backward"),
            )
        };
        let reduce = pipeline("raster_reduce", REDUCE_WGSL, "reduce");
        use wgpu::BufferUsages as U;
        let storage = U::STORAGE | U::COPY_DST | U::COPY_SRC;
        let buffer = |label| GrowBuffer::new(device, label, storage);
        Self {
            params: GrowBuffer::new(device, "params", U::UNIFORM | U::COPY_DST),
            splats: buffer("splats"),
            sorted_splats: buffer("sorted_splats"),
            tile_offsets: buffer("tile_offsets"),
            splat_offsets: buffer("splat_offsets"),
            sorted_position: buffer("sorted_position"),
            rgba: buffer("rgba"),
            final_transmittance: buffer("final_transmittance"),
            contributors: buffer("contributors"),
            d_color: buffer("d_color"),
            entry_grads: buffer("entry_grads"),
            splat_grads: buffer("splat_grads"),
            staging: GrowBuffer::new(device, "staging", U::MAP_READ | U::COPY_DST),
            forward,
            backward,
            atomics,
            pixel_rows: rows,
            reduce,
            gpu,
            bins: TileBins::default(),
            host_splats: Vec::new(),
            host_rgba: Vec::new(),
            host_grads: Vec::new(),
            tiles: (0, 0),
            entries: 0,
            count: 0,
        }
    }

    /// The adapter in use and the backward's summation, for reports.
    pub fn describe(&self) -> String {
        let sums = if self.atomics {
            "float atomics"
        } else {
            "per-tile sums"
        };
        let rows = self.pixel_rows;
        let per = if rows == 1 {
            "1 pixel".to_string()
        } else {
            format!("{rows} pixels")
        };
        format!(
            "{}, {per} per invocation, backward with {sums}",
            self.gpu.describe()
        )
    }

    /// Whether the backward uses float atomics (the fast path) rather than per-tile sums.
    pub fn uses_float_atomics(&self) -> bool {
        self.atomics
    }

    /// Number of (tile, splat) pairs in the last forward pass.
    pub fn intersections(&self) -> usize {
        self.entries
    }

    /// Renders `splats` into a `width × height` image over `background` (see
    /// [`crate::raster::Rasterizer::forward`]).
    pub fn forward(
        &mut self,
        splats: &[Splat],
        width: usize,
        height: usize,
        background: [f32; 3],
        out: &mut RenderOutput,
    ) -> Result<(), GpuError> {
        self.bins.build(splats, width, height);
        self.tiles = (self.bins.tiles_x as u32, self.bins.tiles_y as u32);
        (self.entries, self.count) = (self.bins.entry_count(), splats.len());
        self.upload_params(width, height, background);
        let gpu = &self.gpu;
        self.host_splats.clear();
        self.host_splats.extend(splats.iter().map(|s| GpuSplat {
            mean: s.mean2d.to_array(),
            extent: s.extent.to_array(),
            conic: [s.conic[0], s.conic[1], s.conic[2], min_power(s.opacity)],
            color: [s.color[0], s.color[1], s.color[2], s.opacity],
        }));
        self.splats.upload(gpu, &self.host_splats);
        self.sorted_splats.upload(gpu, &self.bins.sorted_splats);
        self.tile_offsets.upload(gpu, &self.bins.tile_offsets);
        self.draw(width, height, out)
    }

    fn upload_params(&mut self, width: usize, height: usize, background: [f32; 3]) {
        self.params.upload(
            &self.gpu,
            &[Params {
                width: width as u32,
                height: height as u32,
                tiles_x: self.tiles.0,
                tiles_y: self.tiles.1,
                background: [background[0], background[1], background[2], 0.0],
            }],
        );
    }

    /// [`GpuRasterizer::forward`] of `count` splats already on the GPU: `splats` holds them
    /// in the shaders' layout (`Splat` in `shaders/raster_common.wgsl`, 12 floats each) and
    /// `binner` their bins ([`super::GpuBinner::bin`] for this image size). Only the image
    /// comes back; the splats and bins are copied on the device for the backward pass
    /// ([`GpuRasterizer::backward_resident`]).
    #[allow(clippy::too_many_arguments)]
    pub fn forward_resident(
        &mut self,
        splats: &wgpu::Buffer,
        count: usize,
        binner: &super::GpuBinner,
        width: usize,
        height: usize,
        background: [f32; 3],
        out: &mut RenderOutput,
    ) -> Result<(), GpuError> {
        let (tx, ty) = binner.tiles();
        self.tiles = (tx as u32, ty as u32);
        (self.entries, self.count) = (binner.entry_count(), count);
        self.upload_params(width, height, background);
        let bins = binner.buffers();
        let entry_bytes = 4 * self.entries as u64;
        let device = &self.gpu.device;
        let copies = [
            (&mut self.splats, splats, (count * 48) as u64),
            (&mut self.sorted_splats, bins.sorted_splats, entry_bytes),
            (
                &mut self.tile_offsets,
                bins.tile_offsets,
                4 * (tx * ty + 1) as u64,
            ),
            (
                &mut self.splat_offsets,
                bins.splat_offsets,
                4 * (count + 1) as u64,
            ),
            (&mut self.sorted_position, bins.sorted_position, entry_bytes),
        ];
        let mut encoder = device.create_command_encoder(&Default::default());
        for (target, source, bytes) in copies {
            target.reserve(device, bytes);
            if bytes > 0 {
                encoder.copy_buffer_to_buffer(source, 0, &target.buffer, 0, bytes);
            }
        }
        self.gpu.queue.submit([encoder.finish()]);
        self.draw(width, height, out)
    }

    /// Blends the uploaded splats and bins into `out`.
    fn draw(
        &mut self,
        width: usize,
        height: usize,
        out: &mut RenderOutput,
    ) -> Result<(), GpuError> {
        let pixels = width * height;
        let gpu = &self.gpu;
        let rgba_bytes = (pixels * 16) as u64;
        self.rgba.reserve(&gpu.device, rgba_bytes);
        self.final_transmittance
            .reserve(&gpu.device, (pixels * 4) as u64);
        self.contributors.reserve(&gpu.device, (pixels * 4) as u64);
        self.staging.reserve(&gpu.device, rgba_bytes);

        let bind_group = bind(
            gpu,
            &self.forward,
            &[
                &self.params,
                &self.splats,
                &self.sorted_splats,
                &self.tile_offsets,
                &self.rgba,
                &self.final_transmittance,
                &self.contributors,
            ],
        );
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        dispatch_grid(&mut encoder, &self.forward, &bind_group, self.tiles);
        encoder.copy_buffer_to_buffer(&self.rgba.buffer, 0, &self.staging.buffer, 0, rgba_bytes);
        gpu.queue.submit([encoder.finish()]);
        gpu.read_back(&self.staging.buffer, rgba_bytes, &mut self.host_rgba)?;

        out.image.width = width;
        out.image.height = height;
        out.image.data.clear();
        out.image
            .data
            .extend(self.host_rgba.iter().map(|p| [p[0], p[1], p[2]]));
        out.alpha.clear();
        out.alpha.extend(self.host_rgba.iter().map(|p| p[3]));
        Ok(())
    }

    /// Back-propagates `d_color` (row-major, the size of the last forward) to one gradient per
    /// splat of the last [`GpuRasterizer::forward`] call, whose `splats` it must be given.
    pub fn backward(
        &mut self,
        splats: &[Splat],
        d_color: &[[f32; 3]],
        grads: &mut Vec<SplatGrad>,
    ) -> Result<(), GpuError> {
        debug_assert_eq!(
            splats.len(),
            self.count,
            "the splats of the last forward pass"
        );
        if !self.atomics {
            self.splat_offsets
                .upload(&self.gpu, self.bins.splat_offsets());
            self.sorted_position
                .upload(&self.gpu, self.bins.sorted_position());
        }
        let grad_bytes = (self.count * FIELDS * 4) as u64;
        self.staging.reserve(&self.gpu.device, grad_bytes);
        let mut encoder = self.encode_backward(d_color);
        if grad_bytes > 0 {
            encoder.copy_buffer_to_buffer(
                &self.splat_grads.buffer,
                0,
                &self.staging.buffer,
                0,
                grad_bytes,
            );
        }
        let gpu = &self.gpu;
        gpu.queue.submit([encoder.finish()]);
        gpu.read_back(&self.staging.buffer, grad_bytes, &mut self.host_grads)?;

        grads.clear();
        grads.extend(self.host_grads.iter().map(|g| SplatGrad {
            mean2d: glam::Vec2::new(g[0], g[1]),
            conic: [g[2], g[3], g[4]],
            opacity: g[5],
            color: [g[6], g[7], g[8]],
        }));
        Ok(())
    }

    /// [`GpuRasterizer::backward`] after [`GpuRasterizer::forward_resident`]: the splat
    /// gradients stay on the GPU, in the returned buffer (9 floats per splat: mean 2, conic
    /// 3, opacity, colour 3, the layout of the deformer's splat gradients). Submits the work
    /// without waiting for it.
    pub fn backward_resident(&mut self, d_color: &[[f32; 3]]) -> &wgpu::Buffer {
        let encoder = self.encode_backward(d_color);
        self.gpu.queue.submit([encoder.finish()]);
        &self.splat_grads.buffer
    }

    /// Uploads `d_color` and records the blending backward of the last forward pass into
    /// the splat-gradient buffer (the bins' splat offsets and sorted positions must already
    /// be on the GPU for the per-tile sums).
    fn encode_backward(&mut self, d_color: &[[f32; 3]]) -> wgpu::CommandEncoder {
        let gpu = &self.gpu;
        let entries = self.entries;
        let count = self.count;
        self.d_color.upload(gpu, d_color);
        let entry_bytes = (entries * FIELDS * 4) as u64;
        if !self.atomics {
            self.entry_grads.reserve(&gpu.device, entry_bytes);
        }
        let grad_bytes = (count * FIELDS * 4) as u64;
        self.splat_grads.reserve(&gpu.device, grad_bytes);

        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        // The shared bindings 0–6; binding 7 is what the shares are summed into.
        let mut bindings = vec![
            &self.params,
            &self.splats,
            &self.sorted_splats,
            &self.tile_offsets,
            &self.final_transmittance,
            &self.contributors,
            &self.d_color,
        ];
        if self.atomics {
            bindings.push(&self.splat_grads);
            if grad_bytes > 0 {
                encoder.clear_buffer(&self.splat_grads.buffer, 0, Some(grad_bytes));
            }
            let backward = bind(gpu, &self.backward, &bindings);
            dispatch_grid(&mut encoder, &self.backward, &backward, self.tiles);
        } else {
            bindings.push(&self.entry_grads);
            // Entries behind every pixel's last contributor get no share: they stay zero.
            if entry_bytes > 0 {
                encoder.clear_buffer(&self.entry_grads.buffer, 0, Some(entry_bytes));
            }
            let backward = bind(gpu, &self.backward, &bindings);
            dispatch_grid(&mut encoder, &self.backward, &backward, self.tiles);
            let reduce = bind(
                gpu,
                &self.reduce,
                &[
                    &self.splat_offsets,
                    &self.sorted_position,
                    &self.entry_grads,
                    &self.splat_grads,
                ],
            );
            let groups = (count as u32).div_ceil(REDUCE_GROUP);
            let across = groups.min(MAX_GROUPS);
            dispatch_grid(
                &mut encoder,
                &self.reduce,
                &reduce,
                (across, groups.div_ceil(across.max(1))),
            );
        }
        encoder
    }
}

/// A bind group of `buffers` at bindings 0, 1, 2, … of the pipeline's group 0.
fn bind(
    gpu: &GpuContext,
    pipeline: &wgpu::ComputePipeline,
    buffers: &[&GrowBuffer],
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.binding(),
        })
        .collect();
    gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}
