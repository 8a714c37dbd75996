//! The GPU-resident training iteration: [`GpuTraining`] chains deformation and projection,
//! tile binning, blending, the blending and parameter backward passes, a non-finite gradient
//! check, Adam and the densification statistics on buffers that stay on the device between
//! densification steps (`shaders/pipeline.wgsl` glues the stages).
//!
//! Per iteration the host uploads the warped times (computed by the CPU time-warp stage, 8
//! bytes per Gaussian), the camera and settings uniforms and dL/dcolour, and reads back the
//! rendered image (for the CPU loss), the number of binned entries (to size the sort) and 4
//! bytes of the gradient check. Parameters, gradients, Adam moments and statistics come back
//! only on [`GpuTraining::read`] (before densification, checkpoints, export and evaluation),
//! and go up again on [`GpuTraining::upload`] after the population changed.

use bytemuck::{Pod, Zeroable};

use super::deform::NO_FAULT;
use super::kernel::{self, bind, dispatch, groups_for, storage};
use super::{
    DeformSettings, GpuAdam, GpuBinner, GpuContext, GpuDeformer, GpuError, GpuRasterizer, GpuStats,
    GrowBuffer, SplatBox, StatsConfig,
};
use crate::components::{GradAccum, Temporal, WarpedTime};
use crate::data::Camera;
use crate::layout::{PARAM_FLOATS, SECTION_NAMES, SECTIONS, WIDTHS, group_range};
use crate::raster::RenderOutput;

const PIPELINE_WGSL: &str = include_str!("../../shaders/pipeline.wgsl");

/// Floats per projected splat record of the deformer (`SPLAT_STRIDE`).
const SPLAT_FLOATS: u64 = 16;
/// Floats per splat of the rasterizer (`Splat` in `shaders/raster_common.wgsl`).
const RASTER_SPLAT_FLOATS: u64 = 12;

/// `PipelineParams` in `shaders/pipeline.wgsl`.
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
#[repr(C)]
struct PipelineParams {
    count: u32,
    grad_len: u32,
    pad: [u32; 2],
}

/// The first non-finite parameter gradient found by [`GpuTraining::backward`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GradientFault {
    /// The parameter group ([`crate::components::Param::NAME`]).
    pub group: &'static str,
    /// The Gaussian's slot.
    pub gaussian: usize,
}

/// Parameters, Adam moments and statistics read back by [`GpuTraining::read`]: `params`, `m`
/// and `v` in the resident layout (section by section in [`SECTION_NAMES`] order, each
/// Gaussian-major with the component's fields in declaration order), `accum` one per slot.
#[derive(Clone, Debug, Default)]
pub struct ResidentState {
    /// Parameter values.
    pub params: Vec<f32>,
    /// Adam first moments.
    pub m: Vec<f32>,
    /// Adam second moments.
    pub v: Vec<f32>,
    /// Densification statistics.
    pub accum: Vec<GradAccum>,
}

impl ResidentState {
    /// Clears every array.
    pub fn clear(&mut self) {
        self.params.clear();
        self.m.clear();
        self.v.clear();
        self.accum.clear();
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.params.len() / PARAM_FLOATS
    }

    /// Whether there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.params.is_empty()
    }
}

/// The whole training iteration on the GPU with resident per-Gaussian buffers (see the
/// module documentation). As a resource it replaces the CPU deformation, splatting, backward,
/// Adam and statistics stages (see `systems::resident`).
#[derive(bevy_ecs::resource::Resource)]
pub struct GpuTraining {
    gpu: GpuContext,
    deformer: GpuDeformer,
    binner: GpuBinner,
    raster: GpuRasterizer,
    stats: GpuStats,
    adam: GpuAdam,
    pack: wgpu::ComputePipeline,
    check: wgpu::ComputePipeline,
    uniform: GrowBuffer,
    raster_splats: GrowBuffer,
    opacity: GrowBuffer,
    m: GrowBuffer,
    v: GrowBuffer,
    fault: GrowBuffer,
    fault_staging: GrowBuffer,
    adam_uniforms: Vec<GrowBuffer>,
    host_fault: Vec<u32>,
    count: usize,
    dirty: bool,
}

impl GpuTraining {
    /// Opens the default GPU (float atomics where offered, see [`GpuContext::new`]) and
    /// builds every stage on it.
    pub fn new() -> Result<Self, GpuError> {
        Self::open(true)
    }

    /// [`GpuTraining::new`], with the float-atomic backward only if `float_atomics` and the
    /// adapter offers it (else the portable per-tile sums; `train.gpu_float_atomics`).
    pub fn open(float_atomics: bool) -> Result<Self, GpuError> {
        Ok(Self::with_context(GpuContext::new(float_atomics)?))
    }

    /// The device the stages run on.
    pub fn context(&self) -> &GpuContext {
        &self.gpu
    }

    /// Builds every stage on one open device.
    pub fn with_context(gpu: GpuContext) -> Self {
        let device = &gpu.device;
        let [pack, check] = kernel::pipelines(device, "pipeline", PIPELINE_WGSL, ["pack", "check"]);
        use wgpu::BufferUsages as U;
        let storage = U::STORAGE | U::COPY_DST | U::COPY_SRC;
        let buffer = |label| GrowBuffer::new(device, label, storage);
        let uniform = |label| GrowBuffer::new(device, label, U::UNIFORM | U::COPY_DST);
        Self {
            deformer: GpuDeformer::with_context(gpu.clone()),
            binner: GpuBinner::new(&gpu),
            raster: GpuRasterizer::with_context(gpu.clone()),
            stats: GpuStats::new(&gpu),
            adam: GpuAdam::new(&gpu),
            pack,
            check,
            uniform: uniform("pipeline_params"),
            raster_splats: buffer("raster_splats"),
            opacity: buffer("splat_opacity"),
            m: buffer("adam_m"),
            v: buffer("adam_v"),
            fault: buffer("gradient_fault"),
            fault_staging: GrowBuffer::new(device, "fault_staging", U::MAP_READ | U::COPY_DST),
            adam_uniforms: (0..WIDTHS.len()).map(|_| uniform("adam_params")).collect(),
            host_fault: Vec::new(),
            count: 0,
            dirty: true,
            gpu,
        }
    }

    /// The adapter in use and the blending backward's summation, for reports.
    pub fn describe(&self) -> String {
        format!("{} (GPU-resident training)", self.raster.describe())
    }

    /// Whether the adapter is a software rasterizer on the CPU.
    pub fn is_software(&self) -> bool {
        self.gpu.is_software()
    }

    /// Number of Gaussians on the GPU.
    pub fn len(&self) -> usize {
        self.count
    }

    /// Whether no Gaussians are on the GPU.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Whether the ECS components changed since the last [`GpuTraining::upload`] (true at
    /// first and after [`GpuTraining::mark_dirty`]).
    pub fn is_dirty(&self) -> bool {
        self.dirty
    }

    /// Marks the GPU copy stale: the next iteration uploads the components again.
    pub fn mark_dirty(&mut self) {
        self.dirty = true;
    }

    /// Blocks until the device has finished the work submitted so far (for timing stages).
    pub fn wait(&self) -> Result<(), GpuError> {
        self.gpu.wait()
    }

    /// Number of (tile, splat) pairs of the last forward pass.
    pub fn intersections(&self) -> usize {
        self.raster.intersections()
    }

    /// Replaces the resident state: `state.params`, `m`, `v` in the resident layout (see
    /// [`ResidentState`]) and one statistics record per slot. Gradients are left as they are.
    ///
    /// # Panics
    /// Unless the arrays describe the same number of Gaussians.
    pub fn upload(&mut self, state: &ResidentState) -> Result<(), GpuError> {
        let count = state.accum.len();
        assert!(
            state.params.len() == count * PARAM_FLOATS
                && state.m.len() == state.params.len()
                && state.v.len() == state.params.len(),
            "parameters, moments and statistics of {count} Gaussians"
        );
        self.deformer.reserve(count)?;
        if count > 0 {
            self.gpu.queue.write_buffer(
                self.deformer.params_buffer(),
                0,
                bytemuck::cast_slice(&state.params),
            );
        }
        self.m.upload(&self.gpu, &state.m);
        self.v.upload(&self.gpu, &state.v);
        self.stats.upload_accum(&state.accum);
        self.count = count;
        self.dirty = false;
        Ok(())
    }

    /// Deforms, projects, bins and blends the view: `warped` is one warped time per slot.
    /// Only the image (and the entry count, to size the sort) comes back.
    ///
    /// # Panics
    /// Unless `warped` has [`GpuTraining::len`] entries.
    pub fn forward(
        &mut self,
        warped: &[WarpedTime],
        camera: &Camera,
        settings: &DeformSettings,
        background: [f32; 3],
        out: &mut RenderOutput,
    ) -> Result<(), GpuError> {
        let n = self.count;
        self.deformer.upload_warped_time(warped);
        self.deformer.forward(camera, settings);
        let grad_len = (n * PARAM_FLOATS) as u32;
        self.uniform.upload(
            &self.gpu,
            &[PipelineParams {
                count: n as u32,
                grad_len,
                pad: [0; 2],
            }],
        );
        let device = &self.gpu.device;
        self.raster_splats
            .reserve(device, RASTER_SPLAT_FLOATS * 4 * n as u64);
        self.opacity.reserve(device, 4 * n as u64);
        let boxes = self.binner.boxes_for(n);
        if n > 0 {
            let group = bind(
                device,
                &self.pack,
                vec![
                    (0, self.uniform.buffer.as_entire_binding()),
                    (
                        1,
                        storage(self.deformer.splats_buffer(), SPLAT_FLOATS * 4 * n as u64),
                    ),
                    (2, storage(boxes, (n * size_of::<SplatBox>()) as u64)),
                    (3, self.raster_splats.binding()),
                    (4, self.opacity.binding()),
                ],
            );
            let mut encoder = device.create_command_encoder(&Default::default());
            dispatch(&mut encoder, &self.pack, &group, groups_for(n as u32));
            self.gpu.queue.submit([encoder.finish()]);
        }
        let (width, height) = (camera.width as usize, camera.height as usize);
        self.binner.bin_resident(n, width, height)?;
        self.raster.forward_resident(
            &self.raster_splats.buffer,
            n,
            &self.binner,
            width,
            height,
            background,
            out,
        )
    }

    /// Back-propagates `d_color` (one per pixel of the last forward pass) through blending,
    /// projection and deformation into the resident parameter gradients, and checks them:
    /// returns the first non-finite one (by section, then slot), reading back 4 bytes.
    pub fn backward(&mut self, d_color: &[[f32; 3]]) -> Result<Option<GradientFault>, GpuError> {
        let splat_grads = self.raster.backward_resident(d_color);
        // The parameter backward notes the first non-finite gradient as it writes them.
        self.deformer.backward_resident(splat_grads);
        self.read_fault(false)
    }

    /// The first non-finite resident parameter gradient (by section, then slot), found by
    /// reading the gradients back on the device (the `check` kernel), e.g. after
    /// [`GpuTraining::write_gradient_values`]; reads back 4 bytes.
    pub fn check_gradients(&mut self) -> Result<Option<GradientFault>, GpuError> {
        let n = self.count;
        let grad_len = n * PARAM_FLOATS;
        let device = &self.gpu.device;
        self.fault.reserve(device, 4);
        self.gpu
            .queue
            .write_buffer(&self.fault.buffer, 0, bytemuck::bytes_of(&NO_FAULT));
        if n > 0 {
            let mut encoder = device.create_command_encoder(&Default::default());
            let group = bind(
                device,
                &self.check,
                vec![
                    (0, self.uniform.buffer.as_entire_binding()),
                    // Read as quads (the buffer's size is a multiple of 256 bytes).
                    (
                        5,
                        storage(
                            self.deformer.grads_buffer(),
                            4 * grad_len.next_multiple_of(4) as u64,
                        ),
                    ),
                    (6, self.fault.binding()),
                ],
            );
            dispatch(
                &mut encoder,
                &self.check,
                &group,
                groups_for(grad_len.div_ceil(4) as u32),
            );
            self.gpu.queue.submit([encoder.finish()]);
        }
        self.read_fault(true)
    }

    /// Reads back the fault index of the `check` kernel (`from_check`) or of the last
    /// parameter backward, and names its section and Gaussian.
    fn read_fault(&mut self, from_check: bool) -> Result<Option<GradientFault>, GpuError> {
        let device = &self.gpu.device;
        self.fault_staging.reserve(device, 4);
        let fault = if from_check {
            &self.fault.buffer
        } else {
            self.deformer.fault_buffer()
        };
        let mut encoder = device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(fault, 0, &self.fault_staging.buffer, 0, 4);
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu
            .read_back(&self.fault_staging.buffer, 4, &mut self.host_fault)?;
        let index = self.host_fault[0];
        if index == NO_FAULT {
            return Ok(None);
        }
        let index = index as usize;
        let mut start = 0;
        for (k, width) in WIDTHS.iter().enumerate() {
            let end = start + width * self.count;
            if index < end {
                return Ok(Some(GradientFault {
                    group: SECTION_NAMES[k],
                    gaussian: (index - start) / width,
                }));
            }
            start = end;
        }
        unreachable!("the check reports an index inside the gradient buffer")
    }

    /// One Adam step of every section at global step `iteration`: `rates[k]` are the
    /// per-field learning rates of section `k` (e.g.
    /// [`crate::systems::adam::ParamGroup::learning_rates`] `.values()`).
    ///
    /// # Panics
    /// Unless `rates[k]` has one rate per field of section `k`.
    pub fn adam(&mut self, rates: [&[f32]; SECTIONS], iteration: u32) {
        let n = self.count;
        let mut start = 0;
        for (k, (rates, width)) in rates.into_iter().zip(WIDTHS).enumerate() {
            assert_eq!(rates.len(), width, "one learning rate per field");
            self.adam.step_range(
                &mut self.adam_uniforms[k],
                [
                    self.deformer.params_buffer(),
                    self.deformer.grads_buffer(),
                    &self.m.buffer,
                    &self.v.buffer,
                ],
                start..start + width * n,
                rates,
                iteration,
            );
            start += width * n;
        }
    }

    /// Adds the last view to the densification statistics (with the current temporal
    /// parameters, as the CPU stage does after Adam).
    pub fn accumulate_stats(&mut self, config: &StatsConfig) {
        let temporal = group_range::<Temporal>(self.count, 0).start as u64 * 4;
        self.stats.accumulate_resident(
            config,
            self.binner.buffers().splats,
            &self.opacity.buffer,
            self.deformer.ndc_grad_norm_buffer(),
            (self.deformer.params_buffer(), temporal),
        );
    }

    /// Copies the parameter gradients of the last backward pass into `out` (for tests and
    /// diagnostics; training never needs them on the CPU).
    pub fn read_gradients(&mut self, out: &mut super::ParamGradients) -> Result<(), GpuError> {
        self.deformer.read_grads(out)
    }

    /// Copies the parameter gradients of the last backward pass into `out`, in the resident
    /// layout ([`super::layout::group_range`] finds a group's values).
    pub fn read_gradient_values(&mut self, out: &mut Vec<f32>) -> Result<(), GpuError> {
        self.deformer.read_grad_values(out)
    }

    /// Replaces the gradients of the last backward pass, in the same layout as
    /// [`GpuTraining::read_gradient_values`], before [`GpuTraining::adam`].
    ///
    /// # Panics
    /// Unless `values` holds one gradient per resident value.
    pub fn write_gradient_values(&mut self, values: &[f32]) {
        self.deformer.write_grad_values(values);
    }

    /// Copies the deformed Gaussians of the last forward pass into `out` (one per slot).
    pub fn read_deformed(
        &mut self,
        out: &mut Vec<crate::components::Deformed>,
    ) -> Result<(), GpuError> {
        self.deformer.read_deformed(out)
    }

    /// Copies the parameters, moments and statistics back into `out`.
    pub fn read(&mut self, out: &mut ResidentState) -> Result<(), GpuError> {
        self.deformer.read_params(&mut out.params)?;
        let bytes = 4 * (self.count * PARAM_FLOATS) as u64;
        self.fault_staging.reserve(&self.gpu.device, 2 * bytes);
        if bytes > 0 {
            let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
            encoder.copy_buffer_to_buffer(&self.m.buffer, 0, &self.fault_staging.buffer, 0, bytes);
            encoder.copy_buffer_to_buffer(
                &self.v.buffer,
                0,
                &self.fault_staging.buffer,
                bytes,
                bytes,
            );
            self.gpu.queue.submit([encoder.finish()]);
        }
        self.gpu
            .read_back(&self.fault_staging.buffer, 2 * bytes, &mut out.m)?;
        out.v.clear();
        out.v.extend_from_slice(&out.m[out.m.len() / 2..]);
        out.m.truncate(out.m.len() / 2);
        self.stats.read_accum(&mut out.accum)
    }
}
