//! Exclusive prefix sum of `u32` values on the GPU (`shaders/scan.wgsl`): blocks of 2048 values
//! scanned in workgroup memory, block totals scanned recursively (one level per factor of
//! 2048), then added back. Portable: no subgroup operations, no atomics.

use super::kernel::{self, bind, dispatch, storage};
use super::{GpuContext, GpuError, GrowBuffer};

/// Values scanned by one workgroup (`BLOCK` in `shaders/scan_common.wgsl`).
pub(crate) const BLOCK: u32 = 2048;

const SCAN_WGSL: &str = concat!(
    include_str!("../../shaders/scan_common.wgsl"),
    include_str!("../../shaders/scan.wgsl")
);

/// The GPU prefix sum: pipelines and the buffers of the block-total levels, reused across
/// calls (they grow to the largest input and never shrink).
pub struct GpuScan {
    gpu: GpuContext,
    scan_blocks: wgpu::ComputePipeline,
    add_block_sums: wgpu::ComputePipeline,
    /// Block totals of level 0 (the input), level 1, …
    levels: Vec<GrowBuffer>,
    /// Where the single block of the top level writes its total (never read).
    top: wgpu::Buffer,
    /// Input and output of [`GpuScan::exclusive_scan`].
    data: GrowBuffer,
    staging: GrowBuffer,
}

impl GpuScan {
    /// Builds the pipelines on `gpu`'s device.
    pub fn new(gpu: &GpuContext) -> Self {
        let device = &gpu.device;
        let [scan_blocks, add_block_sums] =
            kernel::pipelines(device, "scan", SCAN_WGSL, ["scan_blocks", "add_block_sums"]);
        use wgpu::BufferUsages as U;
        Self {
            gpu: gpu.clone(),
            scan_blocks,
            add_block_sums,
            levels: Vec::new(),
            top: GrowBuffer::create(device, "scan_top", U::STORAGE, 256),
            data: GrowBuffer::new(device, "scan_data", U::STORAGE | U::COPY_DST | U::COPY_SRC),
            staging: GrowBuffer::new(device, "scan_staging", U::MAP_READ | U::COPY_DST),
        }
    }

    /// Writes the exclusive prefix sums of `values` into `out` (`out[i]` = Σ `values[..i]`,
    /// wrapping on overflow) and returns the total.
    pub fn exclusive_scan(&mut self, values: &[u32], out: &mut Vec<u32>) -> Result<u32, GpuError> {
        let len = values.len() as u32;
        // One more value, 0, whose prefix is the total.
        let bytes = 4 * (len as u64 + 1);
        self.data.reserve(&self.gpu.device, bytes);
        if !values.is_empty() {
            self.gpu
                .queue
                .write_buffer(&self.data.buffer, 0, bytemuck::cast_slice(values));
        }
        self.gpu
            .queue
            .write_buffer(&self.data.buffer, 4 * len as u64, &[0; 4]);
        self.staging.reserve(&self.gpu.device, bytes);
        self.prepare(len + 1);
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        self.encode(&mut encoder, &self.data.buffer, len + 1);
        encoder.copy_buffer_to_buffer(&self.data.buffer, 0, &self.staging.buffer, 0, bytes);
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu.read_back(&self.staging.buffer, bytes, out)?;
        Ok(out.pop().unwrap_or(0))
    }

    /// Makes room for scans of up to `len` values (call before [`GpuScan::encode`]).
    pub(crate) fn prepare(&mut self, len: u32) {
        let mut n = len;
        let mut level = 0;
        while n > BLOCK {
            n = n.div_ceil(BLOCK);
            if self.levels.len() == level {
                self.levels.push(GrowBuffer::new(
                    &self.gpu.device,
                    "scan_level",
                    wgpu::BufferUsages::STORAGE,
                ));
            }
            let bytes = 4 * n as u64;
            if self.levels[level].buffer.size() < bytes {
                self.levels[level].reserve(&self.gpu.device, bytes);
            }
            level += 1;
        }
    }

    /// Records the in-place exclusive scan of the first `len` values of `data` (room for them
    /// made by [`GpuScan::prepare`]).
    pub(crate) fn encode(&self, encoder: &mut wgpu::CommandEncoder, data: &wgpu::Buffer, len: u32) {
        self.encode_level(encoder, data, len, 0);
    }

    fn encode_level(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        data: &wgpu::Buffer,
        len: u32,
        level: usize,
    ) {
        if len == 0 {
            return;
        }
        let device = &self.gpu.device;
        let blocks = len.div_ceil(BLOCK);
        let data_binding = || storage(data, 4 * len as u64);
        if blocks == 1 {
            let group = bind(
                device,
                &self.scan_blocks,
                vec![(0, data_binding()), (1, storage(&self.top, 4))],
            );
            dispatch(encoder, &self.scan_blocks, &group, 1);
            return;
        }
        let sums = &self.levels[level].buffer;
        let sums_binding = || storage(sums, 4 * blocks as u64);
        let group = bind(
            device,
            &self.scan_blocks,
            vec![(0, data_binding()), (1, sums_binding())],
        );
        dispatch(encoder, &self.scan_blocks, &group, blocks);
        self.encode_level(encoder, sums, blocks, level + 1);
        let group = bind(
            device,
            &self.add_block_sums,
            vec![(0, data_binding()), (1, sums_binding())],
        );
        dispatch(encoder, &self.add_block_sums, &group, blocks);
    }
}
