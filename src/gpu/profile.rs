//! Per-kernel GPU times from timestamp queries (`tadgs bench --backend gpu --kernels`).
//!
//! Once [`enable`] has been called (before the device is opened, so that
//! [`super::GpuContext::new`] asks for `TIMESTAMP_QUERY`), every compute pass that
//! [`super::kernel::dispatch_grid`] records writes a timestamp at its start and at its end,
//! and [`take`] sums the device time of the passes recorded since the last call per kernel
//! (pipeline entry point). Off by default: then no pass carries timestamps and this module
//! costs one relaxed atomic load per dispatch.

use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use super::{GpuContext, GpuError};

/// Timestamps per query set (wgpu's largest): 2 048 passes between two [`take`] calls.
const QUERIES: u32 = 4096;

static ENABLED: AtomicBool = AtomicBool::new(false);
static STATE: Mutex<Option<Profiler>> = Mutex::new(None);

/// The device time of one kernel over the passes recorded between two [`take`] calls.
#[derive(Clone, Debug, PartialEq)]
pub struct KernelTime {
    /// "shader label/entry point" (the entry point alone where the two are the same).
    pub kernel: String,
    /// Dispatches (compute passes) recorded.
    pub passes: u32,
    /// Sum of their device time, milliseconds.
    pub ms: f64,
}

struct Profiler {
    device: wgpu::Device,
    query_set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    staging: wgpu::Buffer,
    /// Kernel name of every pipeline built on `device` since [`enable`].
    names: HashMap<wgpu::ComputePipeline, String>,
    /// Kernel of each pass recorded since the last [`take`]; pass k owns queries 2k, 2k + 1.
    passes: Vec<String>,
    /// Passes recorded without timestamps because the query set was full.
    dropped: u32,
}

/// Turns kernel profiling on for the devices opened and the pipelines built from now on.
pub fn enable() {
    ENABLED.store(true, Ordering::Relaxed);
}

/// Whether [`enable`] was called.
pub fn enabled() -> bool {
    ENABLED.load(Ordering::Relaxed)
}

/// Records the kernel name of `pipeline`. The first device to register one while profiling is
/// on (and that was opened with `TIMESTAMP_QUERY`) becomes the profiled device.
pub(crate) fn register(device: &wgpu::Device, pipeline: &wgpu::ComputePipeline, name: String) {
    if !enabled() || !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
        return;
    }
    let mut state = STATE.lock().unwrap();
    let profiler = state.get_or_insert_with(|| Profiler::new(device));
    if profiler.device == *device {
        profiler.names.insert(pipeline.clone(), name);
    }
}

impl Profiler {
    fn new(device: &wgpu::Device) -> Self {
        let bytes = QUERIES as u64 * 8;
        let buffer = |label, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage,
                mapped_at_creation: false,
            })
        };
        use wgpu::BufferUsages as U;
        Self {
            device: device.clone(),
            query_set: device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("kernel timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: QUERIES,
            }),
            resolve: buffer("kernel timestamps", U::QUERY_RESOLVE | U::COPY_SRC),
            staging: buffer("kernel timestamps staging", U::MAP_READ | U::COPY_DST),
            names: HashMap::new(),
            passes: Vec::new(),
            dropped: 0,
        }
    }
}

/// Begins a compute pass of `pipeline`, with start and end timestamps when it is a profiled
/// kernel and the query set has room.
pub(crate) fn begin_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
) -> wgpu::ComputePass<'e> {
    if !enabled() {
        return encoder.begin_compute_pass(&Default::default());
    }
    let mut state = STATE.lock().unwrap();
    let Some(profiler) = state.as_mut() else {
        return encoder.begin_compute_pass(&Default::default());
    };
    let Some(name) = profiler.names.get(pipeline).cloned() else {
        return encoder.begin_compute_pass(&Default::default());
    };
    let index = 2 * profiler.passes.len() as u32;
    if index + 2 > QUERIES {
        profiler.dropped += 1;
        return encoder.begin_compute_pass(&Default::default());
    }
    profiler.passes.push(name);
    encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: None,
        timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
            query_set: &profiler.query_set,
            beginning_of_pass_write_index: Some(index),
            end_of_pass_write_index: Some(index + 1),
        }),
    })
}

/// Waits for the work submitted on `gpu` and returns the device time per kernel of the passes
/// recorded since the last call (in the order each kernel first ran), then starts afresh.
/// Empty when profiling is off or `gpu` is not the profiled device. Fails if passes were
/// recorded without timestamps because more than 2 048 ran between two calls.
pub fn take(gpu: &GpuContext) -> Result<Vec<KernelTime>, GpuError> {
    let mut state = STATE.lock().unwrap();
    let Some(profiler) = state.as_mut().filter(|p| p.device == gpu.device) else {
        return Ok(Vec::new());
    };
    let passes = std::mem::take(&mut profiler.passes);
    let dropped = std::mem::take(&mut profiler.dropped);
    if dropped > 0 {
        return Err(GpuError::Readback(format!(
            "kernel profile: {dropped} passes ran after the first {} without timestamps; \
             take the times more often",
            QUERIES / 2
        )));
    }
    if passes.is_empty() {
        return Ok(Vec::new());
    }
    let queries = 2 * passes.len() as u32;
    let bytes = queries as u64 * 8;
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    encoder.resolve_query_set(&profiler.query_set, 0..queries, &profiler.resolve, 0);
    encoder.copy_buffer_to_buffer(&profiler.resolve, 0, &profiler.staging, 0, bytes);
    gpu.queue.submit([encoder.finish()]);
    let mut ticks: Vec<u64> = Vec::new();
    gpu.read_back(&profiler.staging, bytes, &mut ticks)?;
    let ns_per_tick = gpu.queue.get_timestamp_period() as f64;
    let mut times: Vec<KernelTime> = Vec::new();
    for (name, pair) in passes.into_iter().zip(ticks.chunks_exact(2)) {
        // A pass the driver ran with no work may leave end before start; count it as zero.
        let ms = pair[1].saturating_sub(pair[0]) as f64 * ns_per_tick * 1e-6;
        match times.iter_mut().find(|t| t.kernel == name) {
            Some(t) => {
                t.passes += 1;
                t.ms += ms;
            }
            None => times.push(KernelTime {
                kernel: name,
                passes: 1,
                ms,
            }),
        }
    }
    Ok(times)
}
