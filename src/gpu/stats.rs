//! Densification statistics on the GPU (`shaders/stats.wgsl`): what
//! [`crate::systems::densify::accumulate_stats`] adds per Gaussian and view (visibility,
//! optional minimum opacity, VAD weighting by σ(t), TAT lifespan, count, largest screen
//! radius, gradient-weighted time offset), on per-slot GPU buffers.

use bytemuck::{Pod, Zeroable};

use super::kernel::{self, bind, dispatch, groups_for, storage};
use super::sort::SplatBox;
use super::{GpuContext, GpuError, GrowBuffer};
use crate::components::{GradAccum, Temporal};
use crate::model::deform::TemporalOpacity;
use crate::model::warp::TimeWarp;
use crate::raster::Splat;
use crate::resources::Settings;

const STATS_WGSL: &str = include_str!("../../shaders/stats.wgsl");

/// ln 5 as `crate::model::deform` rounds it.
const LN_5: f32 = 1.609_438;

/// What the statistics depend on besides the per-Gaussian data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StatsConfig {
    /// VAD: weight each view's gradient by σ(t) (else by 1).
    pub vad: bool,
    /// Count a view only where σ(t) exceeds this.
    pub min_opacity: Option<f32>,
    /// The temporal opacity form (for the lifespan).
    pub model: TemporalOpacity,
    /// The temporal warp (for the lifespan).
    pub warp: TimeWarp,
    /// The view's normalised time (for the gradient-weighted time offset).
    pub time: f32,
}

impl StatsConfig {
    /// The configuration `accumulate_stats` reads from `settings`, for a view at `time`.
    pub fn from_settings(settings: &Settings, time: f32) -> Self {
        Self {
            vad: settings.densify.vad,
            min_opacity: settings.densify.vad_min_opacity,
            model: settings.opacity,
            warp: settings.warp,
            time,
        }
    }
}

/// `StatsParams` in `shaders/stats.wgsl`.
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
#[repr(C)]
struct StatsParams {
    count: u32,
    vad: u32,
    has_min_opacity: u32,
    min_opacity: f32,
    model: u32,
    w_min: f32,
    asymmetric_k: f32,
    warp: u32,
    rho: f32,
    s_near: f32,
    s_far: f32,
    lambda: f32,
    time: f32,
    one_sided_ends: u32,
    smooth_corners: u32,
    _pad: u32,
}

impl StatsParams {
    fn new(config: &StatsConfig, count: u32) -> Self {
        let (model, w_min) = match config.model {
            TemporalOpacity::Rbf => (0, 0.0),
            TemporalOpacity::Asymmetric { w_min } => (1, w_min),
        };
        let (warp, lambda, rho, one_sided_ends, smooth) = match config.warp {
            TimeWarp::Identity => (0, 0.0, 0.0, false, false),
            TimeWarp::Tow {
                lambda,
                rho,
                one_sided_ends,
                smooth,
            } => (1, lambda, rho, one_sided_ends, smooth),
        };
        Self {
            count,
            vad: u32::from(config.vad),
            has_min_opacity: u32::from(config.min_opacity.is_some()),
            min_opacity: config.min_opacity.unwrap_or(0.0),
            model,
            w_min,
            asymmetric_k: LN_5.sqrt(),
            warp,
            rho,
            // The slopes as TimeWarp computes them (1 for the identity, unused).
            s_near: if warp == 1 { rho / lambda } else { 1.0 },
            s_far: if warp == 1 {
                (1.0 - rho) / (1.0 - lambda)
            } else {
                1.0
            },
            lambda,
            time: config.time,
            one_sided_ends: u32::from(one_sided_ends),
            smooth_corners: u32::from(smooth),
            _pad: 0,
        }
    }
}

/// The densification statistics kernel and its per-slot buffers: the accumulators
/// ([`GradAccum`], one per splat slot) stay on the GPU between views.
pub struct GpuStats {
    gpu: GpuContext,
    pipeline: wgpu::ComputePipeline,
    params: GrowBuffer,
    splats: GrowBuffer,
    opacity: GrowBuffer,
    grad_norm: GrowBuffer,
    temporal: GrowBuffer,
    accum: GrowBuffer,
    staging: GrowBuffer,
    host_boxes: Vec<SplatBox>,
    count: usize,
}

impl GpuStats {
    /// Builds the pipeline on `gpu`'s device.
    pub fn new(gpu: &GpuContext) -> Self {
        let device = &gpu.device;
        let [pipeline] = kernel::pipelines(device, "stats", STATS_WGSL, ["accumulate_stats"]);
        use wgpu::BufferUsages as U;
        let buffer = |label| GrowBuffer::new(device, label, U::STORAGE | U::COPY_DST | U::COPY_SRC);
        Self {
            gpu: gpu.clone(),
            pipeline,
            params: GrowBuffer::new(device, "stats_params", U::UNIFORM | U::COPY_DST),
            splats: buffer("stats_splats"),
            opacity: buffer("stats_opacity"),
            grad_norm: buffer("stats_grad_norm"),
            temporal: buffer("stats_temporal"),
            accum: buffer("stats_accum"),
            staging: GrowBuffer::new(device, "stats_staging", U::MAP_READ | U::COPY_DST),
            host_boxes: Vec::new(),
            count: 0,
        }
    }

    /// Number of slots.
    pub fn len(&self) -> usize {
        self.count
    }

    /// Whether there are no slots.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Replaces the accumulators, one per slot (this sets the number of slots).
    pub fn upload_accum(&mut self, accum: &[GradAccum]) {
        self.count = accum.len();
        self.accum.upload(&self.gpu, accum);
    }

    /// Zeroes `count` accumulators (this sets the number of slots).
    pub fn reset(&mut self, count: usize) {
        self.count = count;
        let bytes = (count * size_of::<GradAccum>()) as u64;
        self.accum.reserve(&self.gpu.device, bytes);
        if bytes > 0 {
            let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
            encoder.clear_buffer(&self.accum.buffer, 0, Some(bytes));
            self.gpu.queue.submit([encoder.finish()]);
        }
    }

    /// Adds one view to every slot's statistics: slot i has the projected splat `splats[i]`,
    /// σ(t) `opacity[i]` (the deformed opacity), the NDC gradient norm `grad_norm[i]` and the
    /// temporal component `temporal[i]`. Submits the work without waiting for it.
    ///
    /// # Panics
    /// If a slice's length differs from the number of slots.
    pub fn accumulate(
        &mut self,
        config: &StatsConfig,
        splats: &[Splat],
        opacity: &[f32],
        grad_norm: &[f32],
        temporal: &[Temporal],
    ) {
        let n = self.count;
        assert!(
            splats.len() == n && opacity.len() == n && grad_norm.len() == n && temporal.len() == n,
            "one splat, opacity, gradient norm and temporal component per slot"
        );
        self.host_boxes.clear();
        self.host_boxes.extend(splats.iter().map(SplatBox::from));
        self.splats.upload(&self.gpu, &self.host_boxes);
        self.opacity.upload(&self.gpu, opacity);
        self.grad_norm.upload(&self.gpu, grad_norm);
        self.temporal.upload(&self.gpu, temporal);
        self.dispatch(config);
    }

    /// [`GpuStats::accumulate`] from GPU buffers: `boxes` ([`SplatBox`]es), `opacity` and
    /// `grad_norm` (one f32 per slot) and the [`Temporal`] components at byte `temporal.1` of
    /// `temporal.0`, copied on the device. Submits the work without waiting for it.
    pub(super) fn accumulate_resident(
        &mut self,
        config: &StatsConfig,
        boxes: &wgpu::Buffer,
        opacity: &wgpu::Buffer,
        grad_norm: &wgpu::Buffer,
        temporal: (&wgpu::Buffer, u64),
    ) {
        let n = self.count;
        let device = &self.gpu.device;
        let copies = [
            (&mut self.splats, boxes, 0, n * size_of::<SplatBox>()),
            (&mut self.opacity, opacity, 0, n * 4),
            (&mut self.grad_norm, grad_norm, 0, n * 4),
            (
                &mut self.temporal,
                temporal.0,
                temporal.1,
                n * size_of::<Temporal>(),
            ),
        ];
        let mut encoder = device.create_command_encoder(&Default::default());
        for (target, source, offset, bytes) in copies {
            target.reserve(device, bytes as u64);
            if bytes > 0 {
                encoder.copy_buffer_to_buffer(source, offset, &target.buffer, 0, bytes as u64);
            }
        }
        self.gpu.queue.submit([encoder.finish()]);
        self.dispatch(config);
    }

    fn dispatch(&mut self, config: &StatsConfig) {
        let n = self.count;
        self.params
            .upload(&self.gpu, &[StatsParams::new(config, n as u32)]);
        if n == 0 {
            return;
        }
        let group = bind(
            &self.gpu.device,
            &self.pipeline,
            vec![
                (0, self.params.buffer.as_entire_binding()),
                (1, self.splats.binding()),
                (2, self.opacity.binding()),
                (3, self.grad_norm.binding()),
                (4, self.temporal.binding()),
                (
                    5,
                    storage(&self.accum.buffer, (n * size_of::<GradAccum>()) as u64),
                ),
            ],
        );
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        dispatch(&mut encoder, &self.pipeline, &group, groups_for(n as u32));
        self.gpu.queue.submit([encoder.finish()]);
    }

    /// Copies the accumulators back.
    pub fn read_accum(&mut self, out: &mut Vec<GradAccum>) -> Result<(), GpuError> {
        let bytes = (self.count * size_of::<GradAccum>()) as u64;
        self.staging.reserve(&self.gpu.device, bytes);
        if bytes > 0 {
            let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
            encoder.copy_buffer_to_buffer(&self.accum.buffer, 0, &self.staging.buffer, 0, bytes);
            self.gpu.queue.submit([encoder.finish()]);
        }
        self.gpu.read_back(&self.staging.buffer, bytes, out)
    }

    /// The accumulators' GPU buffer ([`GradAccum`] layout, one per slot).
    pub fn accum_buffer(&self) -> &wgpu::Buffer {
        &self.accum.buffer
    }
}
