//! The per-Gaussian stages on the GPU: deformation to the view's time, EWA projection to
//! splats, and the parameter gradients, as compute kernels (`shaders/deform.wgsl`,
//! `shaders/project.wgsl`, `shaders/param_backward.wgsl`) that compute what the CPU systems
//! compute ([`crate::systems::deform::deform`], [`crate::systems::splat::project_splat`],
//! [`crate::systems::backward`]) to f32 rounding.
//!
//! # Resident buffers
//!
//! A [`GpuDeformer`] keeps every per-Gaussian array on the device between calls: the
//! parameters (one structure-of-arrays buffer, component by component, in the layout of
//! `shaders/gaussian_common.wgsl`), the warped times, the deformed Gaussians, the splats, the
//! splat gradients, the parameter gradients (same layout as the parameters) and the NDC
//! gradient norms. [`GpuDeformer::forward`] and [`GpuDeformer::backward`] only record
//! dispatches; nothing comes back to the CPU unless a `read_*` method asks for it. The
//! intended use once the training schedule runs on the GPU: upload the parameters after
//! initialisation and after each densification (the only stage that changes the set of
//! Gaussians), let an Adam kernel update them in place from the gradient buffer (whose
//! layout is the parameters' own, so one flat kernel with a learning rate per component
//! section covers every group), feed the splat buffer to the rasterizer and its splat
//! gradients back, and read the components back only before densification, export or a
//! checkpoint. The `read_*` methods serve the parity tests and the current CPU pipeline.
//!
//! Buffers grow to the largest population seen and are never shrunk, and bind groups are
//! rebuilt only when a buffer was reallocated, so steady-state iterations allocate nothing
//! on the device. Only core WGSL is used: no optional wgpu feature is needed.

use bytemuck::{Pod, Zeroable};
use glam::Vec2;

use super::{GpuContext, GpuError, GrowBuffer};
use crate::components::{
    Deformed, Fourier, GaussianParams, Grad, Opacity, Param, Position, Rotation, Scale,
    ShCoefficients, Temporal, WarpedTime,
};
use crate::data::Camera;
use crate::model::deform::{ASYMMETRIC_MAX_WIDTH, MotionBasis, TemporalOpacity};
use crate::model::project::{FOV_CLAMP, LOW_PASS, MIN_OPACITY, NEAR_PLANE};
use crate::raster::{Splat, SplatGrad};
use crate::resources::{Settings, TrainState};
use crate::systems::densify::counts_faded_views;

/// Invocations per workgroup of every kernel here (`WORKGROUP` in the shaders).
const WORKGROUP: u32 = 64;
/// Most workgroups per dispatch dimension.
const MAX_GROUPS: u32 = 65_535;

use crate::layout::{PARAM_FLOATS, WIDTHS, sections_of};

/// f32 values per splat record (`SPLAT_STRIDE`).
const SPLAT_FLOATS: usize = 16;
/// f32 values per splat gradient (`SPLAT_GRAD_STRIDE`, the rasterizer's layout).
const SPLAT_GRAD_FLOATS: usize = 9;
/// A gradient check's "nothing found" (`NO_FAULT` in the shaders).
pub(super) const NO_FAULT: u32 = u32::MAX;

const DEFORM_WGSL: &str = concat!(
    include_str!("../../shaders/param_layout.wgsl"),
    include_str!("../../shaders/gaussian_common.wgsl"),
    include_str!("../../shaders/gaussian_params.wgsl"),
    include_str!("../../shaders/deform.wgsl")
);
const PROJECT_WGSL: &str = concat!(
    include_str!("../../shaders/param_layout.wgsl"),
    include_str!("../../shaders/gaussian_common.wgsl"),
    include_str!("../../shaders/project.wgsl")
);
const BACKWARD_WGSL: &str = concat!(
    include_str!("../../shaders/param_layout.wgsl"),
    include_str!("../../shaders/gaussian_common.wgsl"),
    include_str!("../../shaders/gaussian_params.wgsl"),
    include_str!("../../shaders/param_backward.wgsl")
);

/// Parameter components of a population, one entry per Gaussian and the same length each
/// (the ECS components gathered in slot order).
#[derive(Clone, Copy, Debug)]
pub struct ParamSlices<'a> {
    /// Canonical means.
    pub position: &'a [Position],
    /// Fourier motion.
    pub fourier: &'a [Fourier],
    /// Temporal centres and scales.
    pub temporal: &'a [Temporal],
    /// Spatial opacity logits.
    pub opacity: &'a [Opacity],
    /// Rotation polynomials.
    pub rotation: &'a [Rotation],
    /// Log-scale polynomials.
    pub scale: &'a [Scale],
    /// SH colours, every band (zero above the model's degree).
    pub color: &'a [ShCoefficients],
}

impl ParamSlices<'_> {
    /// Number of Gaussians; panics unless every slice has the same length.
    pub fn len(&self) -> usize {
        let n = self.position.len();
        let lens = [
            self.fourier.len(),
            self.temporal.len(),
            self.opacity.len(),
            self.rotation.len(),
            self.scale.len(),
            self.color.len(),
        ];
        assert!(
            lens.iter().all(|&l| l == n),
            "parameter slices differ in length: {n} positions, others {lens:?}"
        );
        n
    }

    /// Whether there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Each component as raw bytes, in section order.
    pub(super) fn sections(&self) -> [&[u8]; 7] {
        [
            bytemuck::cast_slice(self.position),
            bytemuck::cast_slice(self.fourier),
            bytemuck::cast_slice(self.temporal),
            bytemuck::cast_slice(self.opacity),
            bytemuck::cast_slice(self.rotation),
            bytemuck::cast_slice(self.scale),
            bytemuck::cast_slice(self.color),
        ]
    }
}

/// Parameter gradients read back from the GPU: what `systems::backward::backward_parameters`
/// writes into the [`Grad`] components, one entry per Gaussian in upload order.
#[derive(Clone, Debug, Default)]
pub struct ParamGradients {
    /// dL/d canonical mean.
    pub position: Vec<Grad<Position>>,
    /// dL/d Fourier coefficients and phases.
    pub fourier: Vec<Grad<Fourier>>,
    /// dL/d temporal scale (the centre's entry is always 0).
    pub temporal: Vec<Grad<Temporal>>,
    /// dL/d opacity logit.
    pub opacity: Vec<Grad<Opacity>>,
    /// dL/d rotation polynomial.
    pub rotation: Vec<Grad<Rotation>>,
    /// dL/d log-scale polynomial (d1 is 0 without scale motion).
    pub scale: Vec<Grad<Scale>>,
    /// dL/d SH coefficients (0 above the degree in use).
    pub color: Vec<ShCoefficients>,
}

/// The model options the kernels need, from the [`Settings`] and [`TrainState`] resources.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeformSettings {
    /// How the Fourier motion reads time (phase layout and period).
    pub motion: MotionBasis,
    /// The temporal opacity form.
    pub opacity: TemporalOpacity,
    /// Whether the log-scale velocity d1 is used (`model.scale_motion`).
    pub scale_motion: bool,
    /// SH degree in use (clamped to 3).
    pub sh_degree: u32,
    /// Gaussians nearer than this camera depth are culled (never below [`NEAR_PLANE`]).
    pub near_plane: f32,
    /// Mark the culled splats that `in_frustum` keeps (too faint, or only their opacity-sized
    /// box off the image), for the baseline's statistics under
    /// [`crate::scene::BaselineViews::InFrustum`].
    pub mark_faded: bool,
}

impl DeformSettings {
    /// The options the CPU systems read from these resources.
    pub fn new(settings: &Settings, state: &TrainState) -> Self {
        Self {
            motion: settings.motion_basis(),
            opacity: settings.opacity,
            scale_motion: settings.model.scale_motion,
            sh_degree: state.sh_degree,
            near_plane: settings.train.near_plane,
            mark_faded: counts_faded_views(&settings.densify)
                && state.iteration <= settings.densify.until_iter,
        }
    }
}

/// `Frame` in `shaders/gaussian_common.wgsl`.
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
#[repr(C)]
struct FrameUniform {
    rotation: [[f32; 4]; 3],
    translation: [f32; 4],
    eye: [f32; 4],
    focal: [f32; 4],
    view: [f32; 4],
    cull: [f32; 4],
    temporal: [f32; 4],
    count: u32,
    sh_degree: u32,
    flags: u32,
    opacity_model: u32,
}

impl FrameUniform {
    fn new(camera: &Camera, settings: &DeformSettings, count: u32) -> Self {
        let w = camera.rotation();
        let t = camera.translation();
        let eye = camera.center();
        let (width, height) = (camera.width as f32, camera.height as f32);
        // The Jacobian clamp limits, as src/model/project.rs computes them.
        let lim_x = FOV_CLAMP * 0.5 * width / camera.fx;
        let lim_y = FOV_CLAMP * 0.5 * height / camera.fy;
        let (opacity_model, w_min) = match settings.opacity {
            TemporalOpacity::Rbf => (0, 0.0),
            TemporalOpacity::Asymmetric { w_min } => (1, w_min),
        };
        let flags = u32::from(settings.motion.shared_phase)
            | (u32::from(settings.scale_motion) << 1)
            | (u32::from(settings.mark_faded) << 2);
        Self {
            rotation: [
                w.x_axis.extend(0.0).to_array(),
                w.y_axis.extend(0.0).to_array(),
                w.z_axis.extend(0.0).to_array(),
            ],
            translation: t.extend(0.0).to_array(),
            eye: eye.extend(0.0).to_array(),
            focal: [camera.fx, camera.fy, camera.cx, camera.cy],
            view: [width, height, lim_x, lim_y],
            cull: [
                settings.near_plane.max(NEAR_PLANE),
                MIN_OPACITY,
                LOW_PASS,
                0.0,
            ],
            temporal: [
                w_min,
                ASYMMETRIC_MAX_WIDTH,
                1.0 / settings.motion.period,
                0.0,
            ],
            count,
            sh_degree: settings.sh_degree,
            flags,
            opacity_model,
        }
    }
}

/// A bind group kept until one of its buffers is reallocated.
#[derive(Default)]
struct CachedBindGroup {
    buffers: Vec<wgpu::Buffer>,
    group: Option<wgpu::BindGroup>,
}

impl CachedBindGroup {
    /// The bind group of `buffers` at bindings 0, 1, 2, … of the pipeline's group 0 (whole
    /// buffers: the kernels take the population size from the uniform).
    fn get(
        &mut self,
        gpu: &GpuContext,
        pipeline: &wgpu::ComputePipeline,
        buffers: &[&wgpu::Buffer],
    ) -> &wgpu::BindGroup {
        let same = self.group.is_some() && self.buffers.iter().eq(buffers.iter().copied());
        if !same {
            let entries: Vec<wgpu::BindGroupEntry> = buffers
                .iter()
                .enumerate()
                .map(|(i, b)| wgpu::BindGroupEntry {
                    binding: i as u32,
                    resource: b.as_entire_binding(),
                })
                .collect();
            self.group = Some(gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            }));
            self.buffers = buffers.iter().map(|&b| b.clone()).collect();
        }
        self.group.as_ref().expect("bind group was just built")
    }
}

/// Deformation, projection and parameter gradients on the GPU, with the per-Gaussian arrays
/// resident on the device (see the module documentation).
///
/// One iteration: [`GpuDeformer::upload_components`] (or [`GpuDeformer::upload_params`]) when
/// the parameters changed on the CPU, [`GpuDeformer::upload_warped_time`] for the view's
/// time, [`GpuDeformer::forward`], then after blending [`GpuDeformer::backward`] with the
/// splat gradients; each `read_*` method copies one result back.
///
/// Device needs: no optional feature; at most 7 storage buffers and one uniform buffer per
/// kernel (WebGPU's default limits allow 8 and 12), and one storage binding of 388 bytes per
/// Gaussian for the parameters (and as much for their gradients): about 346 000 Gaussians
/// under the 128 MiB binding limit of lavapipe and WebGPU's defaults, far more on desktop
/// GPUs. A larger upload fails with [`GpuError::TooLarge`].
pub struct GpuDeformer {
    gpu: GpuContext,
    deform: wgpu::ComputePipeline,
    project: wgpu::ComputePipeline,
    backward: wgpu::ComputePipeline,
    frame: GrowBuffer,
    params: GrowBuffer,
    warped: GrowBuffer,
    deformed: GrowBuffer,
    splats: GrowBuffer,
    splat_grads: GrowBuffer,
    grads: GrowBuffer,
    ndc_grad_norm: GrowBuffer,
    /// The smallest flat index of a non-finite gradient of the last backward pass, or
    /// [`NO_FAULT`].
    fault: GrowBuffer,
    staging: GrowBuffer,
    deform_group: CachedBindGroup,
    project_group: CachedBindGroup,
    backward_group: CachedBindGroup,
    /// Gaussians in the parameter buffer.
    count: usize,
    /// Whether the deformed and splat buffers hold a forward pass of the uploaded Gaussians.
    forwarded: bool,
    host_params: Vec<f32>,
    host_splats: Vec<[f32; SPLAT_FLOATS]>,
    host_splat_grads: Vec<[f32; SPLAT_GRAD_FLOATS]>,
    host_grads: Vec<f32>,
}

impl GpuDeformer {
    /// Opens the default GPU (see [`GpuContext::new`]; no optional feature is needed) and
    /// builds the pipelines.
    pub fn new() -> Result<Self, GpuError> {
        Ok(Self::with_context(GpuContext::new(false)?))
    }

    /// Builds the pipelines on an open device (a clone of another stage's [`GpuContext`]
    /// shares its device).
    pub fn with_context(gpu: GpuContext) -> Self {
        let device = &gpu.device;
        // Labelled by shader file, so kernel profiles name them unambiguously.
        let pipeline = |label: &str, source: &str, entry: &str| {
            let [pipeline] = super::kernel::pipelines(device, label, source, [entry]);
            pipeline
        };
        let deform = pipeline("deform", DEFORM_WGSL, "deform");
        let project = pipeline("project", PROJECT_WGSL, "project");
        let backward = pipeline("param_backward", BACKWARD_WGSL, "backward");
        use wgpu::BufferUsages as U;
        let storage = U::STORAGE | U::COPY_DST | U::COPY_SRC;
        let buffer = |label| GrowBuffer::new(device, label, storage);
        let mut frame = GrowBuffer::new(device, "deform_frame", U::UNIFORM | U::COPY_DST);
        frame.reserve(device, size_of::<FrameUniform>() as u64);
        Self {
            frame,
            params: buffer("params"),
            warped: buffer("warped_time"),
            deformed: buffer("deformed"),
            splats: buffer("projected_splats"),
            splat_grads: buffer("param_splat_grads"),
            grads: buffer("param_grads"),
            ndc_grad_norm: buffer("ndc_grad_norm"),
            fault: buffer("gradient_fault"),
            staging: GrowBuffer::new(device, "deform_staging", U::MAP_READ | U::COPY_DST),
            deform,
            project,
            backward,
            gpu,
            deform_group: CachedBindGroup::default(),
            project_group: CachedBindGroup::default(),
            backward_group: CachedBindGroup::default(),
            count: 0,
            forwarded: false,
            host_params: Vec::new(),
            host_splats: Vec::new(),
            host_splat_grads: Vec::new(),
            host_grads: Vec::new(),
        }
    }

    /// The adapter in use, for reports.
    pub fn describe(&self) -> String {
        self.gpu.describe()
    }

    /// Number of Gaussians in the parameter buffer.
    pub fn len(&self) -> usize {
        self.count
    }

    /// Whether the parameter buffer holds no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Makes room for `count` Gaussians' parameters, or fails when the device cannot bind
    /// that many (the parameter buffer is the largest, 388 bytes per Gaussian).
    fn reserve_params(&mut self, count: usize) -> Result<u64, GpuError> {
        let bytes = (count * PARAM_FLOATS * 4) as u64;
        let limits = self.gpu.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        if bytes > limit {
            return Err(GpuError::TooLarge {
                what: "parameter",
                bytes,
                limit,
            });
        }
        self.params.reserve(&self.gpu.device, bytes);
        self.count = count;
        self.forwarded = false;
        Ok(bytes)
    }

    /// Uploads every parameter component and the warped times. Each component is copied
    /// straight into its section of the parameter buffer.
    ///
    /// # Panics
    /// Unless every slice, `warped` included, has the same length.
    pub fn upload_components(
        &mut self,
        params: ParamSlices<'_>,
        warped: &[WarpedTime],
    ) -> Result<(), GpuError> {
        let count = params.len();
        self.reserve_params(count)?;
        let mut offset = 0;
        for section in params.sections() {
            if !section.is_empty() {
                self.gpu
                    .queue
                    .write_buffer(&self.params.buffer, offset, section);
            }
            offset += section.len() as u64;
        }
        self.upload_warped_time(warped);
        Ok(())
    }

    /// [`GpuDeformer::upload_components`] from whole [`GaussianParams`] records (regrouped by
    /// component on the CPU first).
    pub fn upload_params(
        &mut self,
        params: &[GaussianParams],
        warped: &[WarpedTime],
    ) -> Result<(), GpuError> {
        self.reserve_params(params.len())?;
        let host = &mut self.host_params;
        host.clear();
        for section in sections_of(params) {
            host.extend_from_slice(&section);
        }
        debug_assert_eq!(host.len(), params.len() * PARAM_FLOATS);
        if !host.is_empty() {
            self.gpu
                .queue
                .write_buffer(&self.params.buffer, 0, bytemuck::cast_slice(host));
        }
        self.upload_warped_time(warped);
        Ok(())
    }

    /// Uploads the warped times of the view; the parameters stay as they are.
    ///
    /// # Panics
    /// Unless `warped` has [`GpuDeformer::len`] entries.
    pub fn upload_warped_time(&mut self, warped: &[WarpedTime]) {
        assert_eq!(
            warped.len(),
            self.count,
            "one warped time per uploaded Gaussian"
        );
        self.warped.upload(&self.gpu, warped);
    }

    /// Deforms every Gaussian to the view's time and projects it into `camera`: fills the
    /// resident deformed and splat buffers (read them with [`GpuDeformer::read_deformed`] and
    /// [`GpuDeformer::read_splats`]).
    pub fn forward(&mut self, camera: &Camera, settings: &DeformSettings) {
        let n = self.count;
        let uniform = FrameUniform::new(camera, settings, n as u32);
        let gpu = &self.gpu;
        gpu.queue
            .write_buffer(&self.frame.buffer, 0, bytemuck::bytes_of(&uniform));
        self.forwarded = true;
        self.deformed
            .reserve(&gpu.device, (n * size_of::<Deformed>()) as u64);
        self.splats
            .reserve(&gpu.device, (n * SPLAT_FLOATS * 4) as u64);
        if n == 0 {
            return;
        }
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        let group = self.deform_group.get(
            gpu,
            &self.deform,
            &[
                &self.frame.buffer,
                &self.params.buffer,
                &self.warped.buffer,
                &self.deformed.buffer,
            ],
        );
        dispatch(&mut encoder, &self.deform, group, n);
        let group = self.project_group.get(
            gpu,
            &self.project,
            &[
                &self.frame.buffer,
                &self.deformed.buffer,
                &self.splats.buffer,
            ],
        );
        dispatch(&mut encoder, &self.project, group, n);
        gpu.queue.submit([encoder.finish()]);
    }

    /// Back-propagates `splat_grads` (one per Gaussian, from blending the splats of the last
    /// [`GpuDeformer::forward`], whose camera and settings it reuses) to every parameter and
    /// to the NDC gradient norms, into the resident gradient buffers (read them with
    /// [`GpuDeformer::read_grads`] and [`GpuDeformer::read_ndc_grad_norm`]).
    ///
    /// # Panics
    /// Unless `splat_grads` has [`GpuDeformer::len`] entries and a forward pass ran since the
    /// parameters were uploaded.
    pub fn backward(&mut self, splat_grads: &[SplatGrad]) {
        let n = self.count;
        assert_eq!(splat_grads.len(), n, "one splat gradient per Gaussian");
        assert!(
            self.forwarded,
            "GpuDeformer::backward needs a forward pass of the uploaded parameters"
        );
        self.host_splat_grads.clear();
        self.host_splat_grads.extend(splat_grads.iter().map(|g| {
            [
                g.mean2d.x, g.mean2d.y, g.conic[0], g.conic[1], g.conic[2], g.opacity, g.color[0],
                g.color[1], g.color[2],
            ]
        }));
        let gpu = &self.gpu;
        self.splat_grads.upload(gpu, &self.host_splat_grads);
        self.dispatch_backward();
    }

    /// [`GpuDeformer::backward`] with the splat gradients already on the GPU: the first
    /// [`GpuDeformer::len`] records of `splat_grads` (9 floats each: mean 2, conic 3, opacity,
    /// colour 3, as [`super::GpuRasterizer::backward_resident`] leaves them).
    ///
    /// # Panics
    /// Unless a forward pass ran since the parameters were uploaded.
    pub fn backward_resident(&mut self, splat_grads: &wgpu::Buffer) {
        assert!(
            self.forwarded,
            "GpuDeformer::backward needs a forward pass of the uploaded parameters"
        );
        let gpu = &self.gpu;
        let bytes = (self.count * SPLAT_GRAD_FLOATS * 4) as u64;
        self.splat_grads.reserve(&gpu.device, bytes);
        if bytes > 0 {
            let mut encoder = gpu.device.create_command_encoder(&Default::default());
            encoder.copy_buffer_to_buffer(splat_grads, 0, &self.splat_grads.buffer, 0, bytes);
            gpu.queue.submit([encoder.finish()]);
        }
        self.dispatch_backward();
    }

    /// The resident parameters, laid out section by section (see the module documentation).
    pub(super) fn params_buffer(&self) -> &wgpu::Buffer {
        &self.params.buffer
    }

    /// The resident parameter gradients (the parameters' layout).
    pub(super) fn grads_buffer(&self) -> &wgpu::Buffer {
        &self.grads.buffer
    }

    /// The projected splats of the last forward pass (16 floats each).
    pub(super) fn splats_buffer(&self) -> &wgpu::Buffer {
        &self.splats.buffer
    }

    /// The NDC gradient norms of the last backward pass.
    pub(super) fn ndc_grad_norm_buffer(&self) -> &wgpu::Buffer {
        &self.ndc_grad_norm.buffer
    }

    /// The smallest flat index (the resident layout) of a non-finite parameter gradient the
    /// last backward pass wrote, or [`NO_FAULT`] (one `u32`).
    pub(super) fn fault_buffer(&self) -> &wgpu::Buffer {
        &self.fault.buffer
    }

    /// Reserves the parameter buffer for `count` Gaussians without writing it (the caller
    /// fills it).
    pub(super) fn reserve(&mut self, count: usize) -> Result<(), GpuError> {
        self.reserve_params(count).map(|_| ())
    }

    /// Copies the resident parameters back (section by section, `count × width` values each).
    pub(super) fn read_params(&mut self, out: &mut Vec<f32>) -> Result<(), GpuError> {
        let bytes = (self.count * PARAM_FLOATS * 4) as u64;
        read(
            &self.gpu,
            &mut self.staging,
            &self.params.buffer,
            bytes,
            out,
        )
    }

    /// Copies the parameter gradients of the last backward pass into `out`, in the resident
    /// layout of the parameters ([`super::layout`]).
    pub(super) fn read_grad_values(&mut self, out: &mut Vec<f32>) -> Result<(), GpuError> {
        let bytes = (self.count * PARAM_FLOATS * 4) as u64;
        read(&self.gpu, &mut self.staging, &self.grads.buffer, bytes, out)
    }

    /// Replaces the parameter gradients (the resident layout, `count × PARAM_FLOATS` values)
    /// that the next Adam step reads.
    pub(super) fn write_grad_values(&mut self, values: &[f32]) {
        assert_eq!(
            values.len(),
            self.count * PARAM_FLOATS,
            "one gradient per value"
        );
        if !values.is_empty() {
            self.gpu
                .queue
                .write_buffer(&self.grads.buffer, 0, bytemuck::cast_slice(values));
        }
    }

    fn dispatch_backward(&mut self) {
        let n = self.count;
        let gpu = &self.gpu;
        self.grads
            .reserve(&gpu.device, (n * PARAM_FLOATS * 4) as u64);
        self.ndc_grad_norm.reserve(&gpu.device, (n * 4) as u64);
        self.fault.reserve(&gpu.device, 4);
        gpu.queue
            .write_buffer(&self.fault.buffer, 0, bytemuck::bytes_of(&NO_FAULT));
        if n == 0 {
            return;
        }
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        // The kernel writes the gradients of drawn splats' Gaussians only.
        encoder.clear_buffer(&self.grads.buffer, 0, Some((n * PARAM_FLOATS * 4) as u64));
        let group = self.backward_group.get(
            gpu,
            &self.backward,
            &[
                &self.frame.buffer,
                &self.params.buffer,
                &self.warped.buffer,
                &self.deformed.buffer,
                &self.splats.buffer,
                &self.splat_grads.buffer,
                &self.grads.buffer,
                &self.ndc_grad_norm.buffer,
                &self.fault.buffer,
            ],
        );
        dispatch(&mut encoder, &self.backward, group, n);
        gpu.queue.submit([encoder.finish()]);
    }

    /// Copies the deformed Gaussians of the last forward pass into `out`.
    pub fn read_deformed(&mut self, out: &mut Vec<Deformed>) -> Result<(), GpuError> {
        let bytes = (self.count * size_of::<Deformed>()) as u64;
        read(
            &self.gpu,
            &mut self.staging,
            &self.deformed.buffer,
            bytes,
            out,
        )
    }

    /// Copies the splats of the last forward pass into `out` (culled ones are
    /// `Splat::default()`, as on the CPU).
    pub fn read_splats(&mut self, out: &mut Vec<Splat>) -> Result<(), GpuError> {
        let bytes = (self.count * SPLAT_FLOATS * 4) as u64;
        read(
            &self.gpu,
            &mut self.staging,
            &self.splats.buffer,
            bytes,
            &mut self.host_splats,
        )?;
        out.clear();
        out.extend(self.host_splats.iter().map(|r| Splat {
            mean2d: Vec2::new(r[0], r[1]),
            extent: Vec2::new(r[2], r[3]),
            conic: [r[4], r[5], r[6]],
            depth: r[7],
            color: [r[8], r[9], r[10]],
            opacity: r[11],
            visible: r[12] != 0.0,
        }));
        Ok(())
    }

    /// Copies the parameter gradients of the last backward pass into `out`.
    pub fn read_grads(&mut self, out: &mut ParamGradients) -> Result<(), GpuError> {
        let n = self.count;
        let bytes = (n * PARAM_FLOATS * 4) as u64;
        read(
            &self.gpu,
            &mut self.staging,
            &self.grads.buffer,
            bytes,
            &mut self.host_grads,
        )?;
        let mut sections = [&[][..]; 7];
        let mut rest = &self.host_grads[..];
        for (section, width) in sections.iter_mut().zip(WIDTHS) {
            let (head, tail) = rest.split_at(n * width);
            *section = head;
            rest = tail;
        }
        fn fill<P: Param>(out: &mut Vec<Grad<P>>, values: &[f32]) {
            out.clear();
            out.extend(
                bytemuck::cast_slice::<f32, P>(values)
                    .iter()
                    .map(|&p| Grad(p)),
            );
        }
        fill(&mut out.position, sections[0]);
        fill(&mut out.fourier, sections[1]);
        fill(&mut out.temporal, sections[2]);
        fill(&mut out.opacity, sections[3]);
        fill(&mut out.rotation, sections[4]);
        fill(&mut out.scale, sections[5]);
        out.color.clear();
        out.color
            .extend_from_slice(bytemuck::cast_slice(sections[6]));
        Ok(())
    }

    /// Copies ‖∂L/∂μ2D‖ in NDC units per Gaussian (0 for splats not drawn) of the last
    /// backward pass into `out`: the densification statistic of `SplatBuffers::ndc_grad_norm`.
    pub fn read_ndc_grad_norm(&mut self, out: &mut Vec<f32>) -> Result<(), GpuError> {
        let bytes = (self.count * 4) as u64;
        read(
            &self.gpu,
            &mut self.staging,
            &self.ndc_grad_norm.buffer,
            bytes,
            out,
        )
    }
}

/// Copies the first `bytes` of `source` through `staging` into `out`.
fn read<T: Pod>(
    gpu: &GpuContext,
    staging: &mut GrowBuffer,
    source: &wgpu::Buffer,
    bytes: u64,
    out: &mut Vec<T>,
) -> Result<(), GpuError> {
    staging.reserve(&gpu.device, bytes);
    if bytes > 0 {
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        encoder.copy_buffer_to_buffer(source, 0, &staging.buffer, 0, bytes);
        gpu.queue.submit([encoder.finish()]);
    }
    gpu.read_back(&staging.buffer, bytes, out)
}

/// Records one dispatch with an invocation per Gaussian (2D beyond 65 535 workgroups).
fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    bind_group: &wgpu::BindGroup,
    count: usize,
) {
    let groups = (count as u32).div_ceil(WORKGROUP);
    let across = groups.min(MAX_GROUPS);
    super::kernel::dispatch_grid(
        encoder,
        pipeline,
        bind_group,
        (across, groups.div_ceil(across.max(1))),
    );
}
