//! GPU backend (wgpu): every stage of a training iteration but view sampling, time warp, loss
//! and densification as WGSL compute kernels (`shaders/`), each held to its CPU reference by
//! parity tests.
//!
//! What runs where with `backend: Gpu` ([`GpuTraining`], wired in by `systems::resident`):
//!
//! | stage | where |
//! |---|---|
//! | sample view, time warp (Δt' per Gaussian, uploaded: 8 bytes each) | CPU |
//! | deformation + EWA projection ([`GpuDeformer`]) | GPU |
//! | tile binning + depth sort ([`GpuBinner`], [`GpuRadixSort`], [`GpuScan`]) | GPU (one 4-byte readback: the entry count) |
//! | forward blending ([`GpuRasterizer::forward_resident`]) | GPU; the image is read back |
//! | loss 0.8·L1 + 0.2·D-SSIM and dL/dcolour | CPU; dL/dcolour is uploaded |
//! | blending and parameter backward | GPU |
//! | non-finite gradient check | GPU (4-byte readback) |
//! | Adam ([`GpuAdam`], one dispatch per parameter section) | GPU |
//! | densification statistics ([`GpuStats`]) | GPU |
//! | clone / split / prune, opacity reset | CPU, after `resident_sync` reads back the parameters, moments and statistics; the next iteration uploads them again |
//!
//! Parameters, gradients, Adam moments and statistics stay on the device between
//! densification steps. The blending-only path ([`GpuRasterizer`] as a resource: the CPU
//! schedule with forward and backward blending on the GPU, splats and gradients crossing the
//! bus every iteration) remains for worlds that insert it themselves.

mod adam;
mod deform;
mod kernel;
mod pipeline;
pub mod profile;
mod raster;
mod scan;
mod sort;
mod stats;

pub use crate::layout::SECTION_NAMES;
pub use adam::{GpuAdam, GpuParamGroup};
pub use deform::{DeformSettings, GpuDeformer, ParamGradients, ParamSlices};
pub use kernel::set_max_dispatch_width;
pub use pipeline::{GpuTraining, GradientFault, ResidentState};
pub use raster::GpuRasterizer;
pub use scan::GpuScan;
pub use sort::{BinBuffers, BinReadback, GpuBinner, GpuRadixSort, SplatBox};
pub use stats::{GpuStats, StatsConfig};

/// The GPU backend could not start or a transfer failed.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// wgpu found no adapter (no Vulkan, Metal or DX12 driver, or none matching
    /// `WGPU_BACKEND`).
    #[error(
        "no GPU adapter found ({0}); install a Vulkan, Metal or DX12 driver (Mesa's lavapipe works without a GPU) or use `backend: Cpu`"
    )]
    NoAdapter(#[from] wgpu::RequestAdapterError),
    /// `WGPU_BACKEND` is set but names no backend wgpu knows (empty, or misspelt), so no
    /// adapter could ever be found.
    #[error(
        "WGPU_BACKEND={0:?} names no GPU backend; set it to one or more of vulkan, metal, dx12, gl (comma-separated), or unset it"
    )]
    NoBackend(String),
    /// The adapter was found but refused to create a device with the requested features and
    /// limits.
    #[error("the GPU adapter {adapter} refused a device: {source}")]
    Device {
        /// The adapter's name.
        adapter: String,
        /// wgpu's reason.
        source: wgpu::RequestDeviceError,
    },
    /// Mapping or polling a buffer to copy results back to the CPU failed; the message is
    /// wgpu's.
    #[error("reading back a GPU buffer failed: {0}")]
    Readback(String),
    /// The model holds something the GPU backend does not draw.
    #[error("the GPU backend does not draw {0}; use the CPU backend (`backend: Cpu`)")]
    Unsupported(&'static str),
    /// A buffer would exceed what the device can bind in one storage binding.
    #[error(
        "the GPU {what} buffer would need {bytes} bytes, above the device's limit of {limit} bytes per storage binding"
    )]
    TooLarge {
        /// Which buffer.
        what: &'static str,
        /// Bytes it would need.
        bytes: u64,
        /// The device's `max_storage_buffer_binding_size` (or `max_buffer_size` if smaller).
        limit: u64,
    },
}

/// What the fast backward needs: float atomics, and subgroup sums that make them 8–32× fewer.
pub(crate) const FLOAT_ATOMIC_FEATURES: wgpu::Features =
    wgpu::Features::SHADER_FLOAT32_ATOMIC.union(wgpu::Features::SUBGROUP);

/// A wgpu device and queue. Cloning shares them (wgpu handles are reference-counted), so the
/// kernels built on one context work on the same buffers.
#[derive(Clone)]
pub struct GpuContext {
    /// The logical device.
    pub device: wgpu::Device,
    /// Its command queue.
    pub queue: wgpu::Queue,
    /// Name, backend and driver of the adapter in use.
    pub adapter: wgpu::AdapterInfo,
}

impl GpuContext {
    /// Opens the preferred adapter (`WGPU_BACKEND` and `WGPU_POWER_PREF` choose, as in wgpu),
    /// with the adapter's own limits so large scenes fit, and with SHADER_FLOAT32_ATOMIC and
    /// SUBGROUP when `float_atomics` is asked for and the adapter offers both, and with
    /// TIMESTAMP_QUERY when [`profile::enable`] was called and the adapter offers it.
    pub fn new(float_atomics: bool) -> Result<Self, GpuError> {
        let descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        if descriptor.backends.is_empty() {
            let value = std::env::var("WGPU_BACKEND").unwrap_or_default();
            return Err(GpuError::NoBackend(value));
        }
        let instance = wgpu::Instance::new(descriptor);
        let adapter =
            pollster::block_on(
                instance.request_adapter(&wgpu::RequestAdapterOptions {
                    power_preference: wgpu::PowerPreference::from_env()
                        .unwrap_or(wgpu::PowerPreference::HighPerformance),
                    ..Default::default()
                }),
            )?;
        let info = adapter.get_info();
        // The adapter's own limits: the largest buffers and the most bindings it offers.
        let required_limits = adapter.limits();
        let fast = FLOAT_ATOMIC_FEATURES;
        let mut required_features = if float_atomics && adapter.features().contains(fast) {
            fast
        } else {
            wgpu::Features::empty()
        };
        let timestamps = wgpu::Features::TIMESTAMP_QUERY;
        if profile::enabled() && adapter.features().contains(timestamps) {
            required_features |= timestamps;
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("tadgs"),
            required_limits,
            required_features,
            ..Default::default()
        }))
        .map_err(|source| GpuError::Device {
            adapter: info.name.clone(),
            source,
        })?;
        Ok(Self {
            device,
            queue,
            adapter: info,
        })
    }

    /// Whether the adapter is a software rasterizer on the CPU (lavapipe, llvmpipe, WARP).
    pub fn is_software(&self) -> bool {
        self.adapter.device_type == wgpu::DeviceType::Cpu
    }

    /// "name (backend, device type)" of the adapter in use.
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.adapter.name, self.adapter.backend, self.adapter.device_type
        )
    }

    /// Blocks until the device has finished the work submitted so far.
    pub fn wait(&self) -> Result<(), GpuError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| GpuError::Readback(e.to_string()))
    }

    /// Waits for the submitted work and copies the first `bytes` of the mapped `staging`
    /// buffer into `out`.
    fn read_back<T: bytemuck::Pod>(
        &self,
        staging: &wgpu::Buffer,
        bytes: u64,
        out: &mut Vec<T>,
    ) -> Result<(), GpuError> {
        out.clear();
        if bytes == 0 {
            return Ok(());
        }
        let slice = staging.slice(..bytes);
        let (sender, receiver) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |result| {
            let _ = sender.send(result);
        });
        self.wait()?;
        receiver
            .recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            out.extend_from_slice(bytemuck::cast_slice(&view));
        }
        staging.unmap();
        Ok(())
    }
}

/// A buffer that grows (never shrinks) to the largest size asked of it.
struct GrowBuffer {
    buffer: wgpu::Buffer,
    usage: wgpu::BufferUsages,
    label: &'static str,
    /// Bytes in use (≤ the buffer's size).
    len: u64,
}

impl GrowBuffer {
    fn new(device: &wgpu::Device, label: &'static str, usage: wgpu::BufferUsages) -> Self {
        Self {
            buffer: Self::create(device, label, usage, 256),
            usage,
            label,
            len: 0,
        }
    }

    fn create(
        device: &wgpu::Device,
        label: &'static str,
        usage: wgpu::BufferUsages,
        size: u64,
    ) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        })
    }

    /// Makes room for `bytes` (contents are not kept when it grows).
    fn reserve(&mut self, device: &wgpu::Device, bytes: u64) {
        self.len = bytes;
        if bytes > self.buffer.size() {
            // Grow by half again, so a slowly growing scene reallocates rarely.
            let size = (bytes + bytes / 2).next_multiple_of(256);
            self.buffer = Self::create(device, self.label, self.usage, size);
        }
    }

    /// Uploads `data`, growing first when needed.
    fn upload<T: bytemuck::Pod>(&mut self, gpu: &GpuContext, data: &[T]) {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        self.reserve(&gpu.device, bytes.len() as u64);
        if !bytes.is_empty() {
            gpu.queue.write_buffer(&self.buffer, 0, bytes);
        }
    }

    /// The used part as a binding (the whole buffer while empty: bindings cannot be empty),
    /// so `arrayLength` in a shader sees the used length.
    fn binding(&self) -> wgpu::BindingResource<'_> {
        wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer: &self.buffer,
            offset: 0,
            size: std::num::NonZeroU64::new(self.len),
        })
    }
}
