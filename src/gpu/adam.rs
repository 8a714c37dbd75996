//! Adam on the GPU (`shaders/adam.wgsl`): the update of
//! [`crate::systems::adam::adam_step`] on a parameter group held in GPU buffers.

use bytemuck::{Pod, Zeroable};

use super::kernel::{self, bind, dispatch, groups_for, storage};
use super::{GpuContext, GpuError, GrowBuffer};
use crate::model::adam::{BETA1, BETA2, EPSILON};

const ADAM_WGSL: &str = include_str!("../../shaders/adam.wgsl");

/// The most values per Gaussian a parameter group may have: the step sizes per slot live in
/// the kernel's uniform block (`step_sizes` in `shaders/adam.wgsl`).
pub const MAX_STRIDE: usize = 256;

/// `AdamParams` in `shaders/adam.wgsl`.
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
#[repr(C)]
struct AdamParams {
    len: u32,
    stride: u32,
    beta1: f32,
    beta2: f32,
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    bias2: f32,
    epsilon: f32,
    /// First element of the step in the bound arrays.
    offset: u32,
    pad: [u32; 3],
    /// The learning rate of each slot divided by the bias correction 1 − β1^step.
    step_sizes: [[f32; 4]; MAX_STRIDE / 4],
}

/// One parameter group on the GPU: values, gradients and Adam moments as flat `f32` arrays,
/// Gaussian-major with `stride` values per Gaussian (a component's fields in declaration
/// order, as [`crate::components::Param::values`] lays them out).
pub struct GpuParamGroup {
    gpu: GpuContext,
    stride: usize,
    len: usize,
    values: GrowBuffer,
    grads: GrowBuffer,
    m: GrowBuffer,
    v: GrowBuffer,
    params: GrowBuffer,
    staging: GrowBuffer,
    host_read: Vec<f32>,
}

impl GpuParamGroup {
    /// An empty group of `stride` values per Gaussian on `gpu`'s device.
    ///
    /// # Panics
    /// If `stride` is 0 or above [`MAX_STRIDE`].
    pub fn new(gpu: &GpuContext, stride: usize) -> Self {
        assert!(
            (1..=MAX_STRIDE).contains(&stride),
            "a parameter group has 1 to {MAX_STRIDE} values per Gaussian, not {stride}"
        );
        use wgpu::BufferUsages as U;
        let device = &gpu.device;
        let buffer = |label| GrowBuffer::new(device, label, U::STORAGE | U::COPY_DST | U::COPY_SRC);
        Self {
            gpu: gpu.clone(),
            stride,
            len: 0,
            values: buffer("adam_values"),
            grads: buffer("adam_grads"),
            m: buffer("adam_m"),
            v: buffer("adam_v"),
            params: GrowBuffer::new(device, "adam_params", U::UNIFORM | U::COPY_DST),
            staging: GrowBuffer::new(device, "adam_staging", U::MAP_READ | U::COPY_DST),
            host_read: Vec::new(),
        }
    }

    /// Values per Gaussian.
    pub fn stride(&self) -> usize {
        self.stride
    }

    /// Number of values (Gaussians × stride).
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the group holds no values.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Replaces the values and moments (gradients are zeroed).
    ///
    /// # Panics
    /// If the three slices differ in length or their length is not a multiple of the stride.
    pub fn upload(&mut self, values: &[f32], m: &[f32], v: &[f32]) {
        assert!(
            m.len() == values.len() && v.len() == values.len(),
            "one moment pair per value"
        );
        assert_eq!(values.len() % self.stride, 0, "whole Gaussians only");
        self.len = values.len();
        self.values.upload(&self.gpu, values);
        self.m.upload(&self.gpu, m);
        self.v.upload(&self.gpu, v);
        let bytes = 4 * self.len as u64;
        self.grads.reserve(&self.gpu.device, bytes);
        if bytes > 0 {
            let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
            encoder.clear_buffer(&self.grads.buffer, 0, Some(bytes));
            self.gpu.queue.submit([encoder.finish()]);
        }
    }

    /// Replaces the gradients (one per value).
    ///
    /// # Panics
    /// If `grads` has not one value per parameter value.
    pub fn upload_grads(&mut self, grads: &[f32]) {
        assert_eq!(grads.len(), self.len, "one gradient per value");
        self.grads.upload(&self.gpu, grads);
    }

    /// Copies the values and moments back.
    pub fn read(
        &mut self,
        values: &mut Vec<f32>,
        m: &mut Vec<f32>,
        v: &mut Vec<f32>,
    ) -> Result<(), GpuError> {
        let bytes = 4 * self.len as u64;
        self.staging.reserve(&self.gpu.device, 3 * bytes);
        if bytes > 0 {
            let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
            for (i, b) in [&self.values, &self.m, &self.v].into_iter().enumerate() {
                encoder.copy_buffer_to_buffer(
                    &b.buffer,
                    0,
                    &self.staging.buffer,
                    i as u64 * bytes,
                    bytes,
                );
            }
            self.gpu.queue.submit([encoder.finish()]);
        }
        self.gpu
            .read_back(&self.staging.buffer, 3 * bytes, &mut self.host_read)?;
        for (i, out) in [values, m, v].into_iter().enumerate() {
            out.clear();
            out.extend_from_slice(&self.host_read[i * self.len..(i + 1) * self.len]);
        }
        Ok(())
    }

    /// The GPU buffers (values, gradients, m, v), for kernels that fill or read them.
    pub fn buffers(&self) -> [&wgpu::Buffer; 4] {
        [
            &self.values.buffer,
            &self.grads.buffer,
            &self.m.buffer,
            &self.v.buffer,
        ]
    }
}

/// The Adam kernel: [`crate::systems::adam::adam_step`] on a [`GpuParamGroup`].
pub struct GpuAdam {
    gpu: GpuContext,
    pipeline: wgpu::ComputePipeline,
}

impl GpuAdam {
    /// Builds the pipeline on `gpu`'s device.
    pub fn new(gpu: &GpuContext) -> Self {
        let [pipeline] = kernel::pipelines(&gpu.device, "adam", ADAM_WGSL, ["adam"]);
        Self {
            gpu: gpu.clone(),
            pipeline,
        }
    }

    /// One Adam step at global step `iteration` (bias correction for `iteration.max(1)`, as on
    /// the CPU) with the learning rate `rates[slot]` for every value at `slot` of a Gaussian's
    /// stride (e.g. [`crate::systems::adam::ParamGroup::learning_rates`] `.values()`).
    /// Submits the work without waiting for it.
    ///
    /// # Panics
    /// If `rates` has not one rate per slot of the stride.
    pub fn step(&self, group: &mut GpuParamGroup, rates: &[f32], iteration: u32) {
        assert_eq!(rates.len(), group.stride, "one learning rate per slot");
        let [values, grads, m, v] =
            [&group.values, &group.grads, &group.m, &group.v].map(|b| &b.buffer);
        self.step_range(
            &mut group.params,
            [values, grads, m, v],
            0..group.len,
            rates,
            iteration,
        );
    }

    /// One Adam step on the elements `range` of `[values, grads, m, v]` (each at least
    /// `range.end` values long), element `range.start + i` with the rate `rates[i % stride]`,
    /// `stride = rates.len()` (at most [`MAX_STRIDE`]), the uniform block written into
    /// `params`. Submits the work without waiting for it.
    pub(super) fn step_range(
        &self,
        params: &mut GrowBuffer,
        [values, grads, m, v]: [&wgpu::Buffer; 4],
        range: std::ops::Range<usize>,
        rates: &[f32],
        iteration: u32,
    ) {
        let step = iteration.max(1) as i32;
        let bias1 = 1.0 - BETA1.powi(step);
        let bias2 = 1.0 - BETA2.powi(step);
        assert!(
            rates.len() <= MAX_STRIDE,
            "at most {MAX_STRIDE} learning rates per step"
        );
        let mut step_sizes = [[0.0; 4]; MAX_STRIDE / 4];
        for (slot, rate) in rates.iter().enumerate() {
            step_sizes[slot / 4][slot % 4] = rate / bias1;
        }
        let len = range.len();
        params.upload(
            &self.gpu,
            &[AdamParams {
                len: len as u32,
                stride: rates.len() as u32,
                beta1: BETA1,
                beta2: BETA2,
                one_minus_beta1: 1.0 - BETA1,
                one_minus_beta2: 1.0 - BETA2,
                bias2,
                epsilon: EPSILON,
                offset: range.start as u32,
                pad: [0; 3],
                step_sizes,
            }],
        );
        if len == 0 {
            return;
        }
        // The kernel reads and writes whole quads of values (`shaders/adam.wgsl`): up to three
        // past `range.end`, inside every buffer, whose sizes are multiples of 256 bytes.
        let bytes = 4 * range.end.next_multiple_of(4) as u64;
        let bind_group = bind(
            &self.gpu.device,
            &self.pipeline,
            vec![
                (0, params.buffer.as_entire_binding()),
                (2, storage(grads, bytes)),
                (3, storage(values, bytes)),
                (4, storage(m, bytes)),
                (5, storage(v, bytes)),
            ],
        );
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        dispatch(
            &mut encoder,
            &self.pipeline,
            &bind_group,
            groups_for((range.end.div_ceil(4) - range.start / 4) as u32),
        );
        self.gpu.queue.submit([encoder.finish()]);
    }
}
