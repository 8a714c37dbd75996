//! Tile binning and depth sort on the GPU: the same per-tile lists as
//! [`crate::raster::TileBins`], built by compute passes (`shaders/bin.wgsl`) around a portable
//! stable LSD radix sort ([`GpuRadixSort`], `shaders/radix_sort.wgsl`) and a multi-level prefix
//! sum ([`GpuScan`]).
//!
//! The CPU orders each tile's splats by depth, breaking ties by splat index. Here the visible
//! splats are radix-sorted by the bits of their depth (stable, so equal depths stay in index
//! order), each emits one (tile id, entry) pair per tile it covers in that order, and a second
//! stable radix sort on the tile id alone groups the pairs by tile without disturbing the depth
//! order inside a tile. The result equals the CPU's entry for entry.

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::kernel::{self, bind, dispatch, groups_for, storage};
use super::scan::{BLOCK, GpuScan};
use super::{GpuContext, GpuError, GrowBuffer};
use crate::raster::{Splat, TILE};

/// Bits sorted per radix pass.
const DIGIT_BITS: u32 = 4;
/// Digits per pass (`RADIX` in `shaders/radix_sort.wgsl`).
const RADIX: u32 = 1 << DIGIT_BITS;
/// Passes of a full 32-bit key.
const MAX_PASSES: usize = (32 / DIGIT_BITS) as usize;

const SORT_WGSL: &str = concat!(
    include_str!("../../shaders/scan_common.wgsl"),
    include_str!("../../shaders/radix_sort.wgsl")
);
const BIN_WGSL: &str = include_str!("../../shaders/bin.wgsl");

/// What tile binning and the densification statistics read of a splat (`SplatBox` in
/// `shaders/bin.wgsl` and `shaders/stats.wgsl`): its screen box and depth.
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct SplatBox {
    /// [`Splat::mean2d`].
    pub mean: [f32; 2],
    /// [`Splat::extent`].
    pub extent: [f32; 2],
    /// [`Splat::depth`].
    pub depth: f32,
    /// [`Splat::visible`] as 0 or 1.
    pub visible: u32,
}

impl From<&Splat> for SplatBox {
    fn from(s: &Splat) -> Self {
        Self {
            mean: s.mean2d.to_array(),
            extent: s.extent.to_array(),
            depth: s.depth,
            visible: u32::from(s.visible),
        }
    }
}

/// Key and value buffers of one sort; the passes move the pairs back and forth between the
/// two halves.
struct SortBuffers {
    keys: [GrowBuffer; 2],
    values: [GrowBuffer; 2],
    /// `SortSize` in `shaders/radix_sort.wgsl`: the number of pairs.
    count: wgpu::Buffer,
}

impl SortBuffers {
    fn new(device: &wgpu::Device) -> Self {
        use wgpu::BufferUsages as U;
        let usage = U::STORAGE | U::COPY_DST | U::COPY_SRC;
        let buffer = |label| GrowBuffer::new(device, label, usage);
        Self {
            keys: [buffer("sort_keys"), buffer("sort_keys")],
            values: [buffer("sort_values"), buffer("sort_values")],
            count: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("sort_count"),
                size: 16,
                usage: U::UNIFORM | U::COPY_DST,
                mapped_at_creation: false,
            }),
        }
    }

    /// Makes room for `n` pairs in both halves.
    fn reserve(&mut self, device: &wgpu::Device, n: u32) {
        for b in self.keys.iter_mut().chain(&mut self.values) {
            b.reserve(device, 4 * n as u64);
        }
    }
}

/// Stable LSD radix sort of (u32 key, u32 value) pairs on the GPU, 4 bits per pass:
/// per-block digit histograms, a prefix sum over them ([`GpuScan`]) and a scatter that ranks
/// each block's keys in input order. Needs no optional wgpu feature (u32 atomics in workgroup
/// memory only) and handles any count that fits the adapter's buffers.
pub struct GpuRadixSort {
    gpu: GpuContext,
    histogram: wgpu::ComputePipeline,
    scatter: wgpu::ComputePipeline,
    scan: GpuScan,
    /// Uniform `SortPass` of each pass: shift 0, 4, …, 28.
    shifts: [wgpu::Buffer; MAX_PASSES],
    /// Digit counts per block, digit-major, then their prefix sums.
    hist: GrowBuffer,
    /// Input and output of [`GpuRadixSort::sort`].
    own: SortBuffers,
    staging: GrowBuffer,
}

impl GpuRadixSort {
    /// Builds the pipelines on `gpu`'s device.
    pub fn new(gpu: &GpuContext) -> Self {
        let device = &gpu.device;
        let [histogram, scatter] = kernel::pipelines(
            device,
            "radix_sort",
            SORT_WGSL,
            ["histogram_pass", "scatter_pass"],
        );
        let shifts = std::array::from_fn(|p| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("sort_pass"),
                contents: bytemuck::cast_slice(&[p as u32 * DIGIT_BITS, 0, 0, 0]),
                usage: wgpu::BufferUsages::UNIFORM,
            })
        });
        use wgpu::BufferUsages as U;
        Self {
            gpu: gpu.clone(),
            histogram,
            scatter,
            scan: GpuScan::new(gpu),
            shifts,
            hist: GrowBuffer::new(device, "sort_histogram", U::STORAGE),
            own: SortBuffers::new(device),
            staging: GrowBuffer::new(device, "sort_staging", U::MAP_READ | U::COPY_DST),
        }
    }

    /// Sorts the pairs `(keys[i], values[i])` by key, keeping pairs with equal keys in input
    /// order, and returns them in `out_keys` and `out_values`. Every key must be below
    /// 2^`bits`: the sort looks at the low `bits` bits only (rounded up to a multiple of 4),
    /// so fewer bits mean fewer passes.
    ///
    /// # Panics
    /// If `keys` and `values` differ in length.
    pub fn sort(
        &mut self,
        keys: &[u32],
        values: &[u32],
        bits: u32,
        out_keys: &mut Vec<u32>,
        out_values: &mut Vec<u32>,
    ) -> Result<(), GpuError> {
        assert_eq!(keys.len(), values.len(), "one value per key");
        let n = keys.len() as u32;
        let bytes = 4 * n as u64;
        self.own.reserve(&self.gpu.device, n);
        if n > 0 {
            let queue = &self.gpu.queue;
            queue.write_buffer(&self.own.keys[0].buffer, 0, bytemuck::cast_slice(keys));
            queue.write_buffer(&self.own.values[0].buffer, 0, bytemuck::cast_slice(values));
        }
        self.prepare(n);
        self.staging.reserve(&self.gpu.device, 2 * bytes);
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        let result = self.encode(&mut encoder, &self.own, n, bits);
        if n > 0 {
            let staging = &self.staging.buffer;
            encoder.copy_buffer_to_buffer(&self.own.keys[result].buffer, 0, staging, 0, bytes);
            let values = &self.own.values[result].buffer;
            encoder.copy_buffer_to_buffer(values, 0, staging, bytes, bytes);
        }
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu
            .read_back(&self.staging.buffer, 2 * bytes, out_keys)?;
        out_values.clear();
        out_values.extend_from_slice(&out_keys[n as usize..]);
        out_keys.truncate(n as usize);
        Ok(())
    }

    /// Makes room for sorting up to `n` pairs (call before [`GpuRadixSort::encode`]).
    fn prepare(&mut self, n: u32) {
        let hist_len = RADIX * n.div_ceil(BLOCK);
        let bytes = 4 * hist_len as u64;
        if self.hist.buffer.size() < bytes {
            self.hist.reserve(&self.gpu.device, bytes);
        }
        self.scan.prepare(hist_len);
    }

    /// Records the sort of the first `n` pairs of `bufs.keys[0]` / `bufs.values[0]` by keys
    /// below 2^`bits`; returns which half of `bufs` holds the result.
    fn encode(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        bufs: &SortBuffers,
        n: u32,
        bits: u32,
    ) -> usize {
        if n == 0 {
            return 0;
        }
        let device = &self.gpu.device;
        self.gpu
            .queue
            .write_buffer(&bufs.count, 0, bytemuck::cast_slice(&[n, 0, 0, 0]));
        let passes = bits.min(32).div_ceil(DIGIT_BITS) as usize;
        let blocks = n.div_ceil(BLOCK);
        let hist_len = RADIX * blocks;
        let bytes = 4 * n as u64;
        // The kernels read keys and values as quads (buffer sizes are multiples of 256 bytes).
        let quad_bytes = bytes.next_multiple_of(16);
        let hist = || storage(&self.hist.buffer, 4 * hist_len as u64);
        let count = || bufs.count.as_entire_binding();
        for p in 0..passes {
            let (src, dst) = (p % 2, 1 - p % 2);
            let shift = || self.shifts[p].as_entire_binding();
            let keys_in = || storage(&bufs.keys[src].buffer, quad_bytes);
            let group = bind(
                device,
                &self.histogram,
                vec![(0, shift()), (1, keys_in()), (5, hist()), (6, count())],
            );
            dispatch(encoder, &self.histogram, &group, blocks);
            self.scan.encode(encoder, &self.hist.buffer, hist_len);
            let group = bind(
                device,
                &self.scatter,
                vec![
                    (0, shift()),
                    (1, keys_in()),
                    (2, storage(&bufs.values[src].buffer, quad_bytes)),
                    (3, storage(&bufs.keys[dst].buffer, bytes)),
                    (4, storage(&bufs.values[dst].buffer, bytes)),
                    (5, hist()),
                    (6, count()),
                ],
            );
            dispatch(encoder, &self.scatter, &group, blocks);
        }
        passes % 2
    }
}

/// `BinParams` in `shaders/bin.wgsl`.
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
#[repr(C)]
struct BinParams {
    tiles_x: u32,
    tiles_y: u32,
    splat_count: u32,
    tile_count: u32,
}

/// The result of [`GpuBinner::bin`] copied back to the CPU, laid out like the fields of
/// [`crate::raster::TileBins`] of the same name.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BinReadback {
    /// Tile t owns sorted entries `tile_offsets[t]..tile_offsets[t + 1]` (tiles + 1 values).
    pub tile_offsets: Vec<u32>,
    /// The splat index of each sorted entry (by tile, then depth, then splat index).
    pub sorted_splats: Vec<u32>,
    /// Splat s owns entries `splat_offsets[s]..splat_offsets[s + 1]` in splat-major order
    /// (splats + 1 values).
    pub splat_offsets: Vec<u32>,
    /// Position in the sorted order of each splat-major entry.
    pub sorted_position: Vec<u32>,
}

/// The GPU buffers of the last [`GpuBinner::bin`], for kernels that follow it; each holds
/// `u32` values, as many as [`BinReadback`]'s field of the same name.
#[derive(Clone, Copy, Debug)]
pub struct BinBuffers<'a> {
    /// [`BinReadback::tile_offsets`].
    pub tile_offsets: &'a wgpu::Buffer,
    /// [`BinReadback::sorted_splats`].
    pub sorted_splats: &'a wgpu::Buffer,
    /// [`BinReadback::splat_offsets`].
    pub splat_offsets: &'a wgpu::Buffer,
    /// [`BinReadback::sorted_position`].
    pub sorted_position: &'a wgpu::Buffer,
    /// The binned splats as [`SplatBox`]es.
    pub splats: &'a wgpu::Buffer,
}

/// Tile binning and per-tile depth sort on the GPU, equal to [`crate::raster::TileBins::build`]
/// entry for entry. Pipelines and buffers are reused; buffers grow to the largest input and
/// stay on the GPU ([`GpuBinner::buffers`]) for the kernels that follow.
pub struct GpuBinner {
    gpu: GpuContext,
    count_tiles: wgpu::ComputePipeline,
    depth_counts: wgpu::ComputePipeline,
    emit: wgpu::ComputePipeline,
    finish: wgpu::ComputePipeline,
    tile_ranges: wgpu::ComputePipeline,
    sort: GpuRadixSort,
    params: GrowBuffer,
    splats: GrowBuffer,
    rects: GrowBuffer,
    splat_offsets: GrowBuffer,
    /// Depth keys and splat indices, sorted by depth.
    depth: SortBuffers,
    /// Which half of `depth` holds the sorted order.
    depth_result: usize,
    depth_offsets: GrowBuffer,
    /// Tile ids and splat-major entry numbers, sorted by tile.
    tiles: SortBuffers,
    entry_splat: GrowBuffer,
    sorted_splats: GrowBuffer,
    sorted_position: GrowBuffer,
    tile_offsets: GrowBuffer,
    count_staging: GrowBuffer,
    staging: GrowBuffer,
    host_boxes: Vec<SplatBox>,
    host_values: Vec<u32>,
    splat_count: u32,
    entries: u32,
    tiles_xy: (u32, u32),
}

impl GpuBinner {
    /// Builds the pipelines on `gpu`'s device.
    pub fn new(gpu: &GpuContext) -> Self {
        let device = &gpu.device;
        let [count_tiles, depth_counts, emit, finish, tile_ranges] = kernel::pipelines(
            device,
            "bin",
            BIN_WGSL,
            [
                "count_tiles",
                "depth_counts",
                "emit",
                "finish",
                "tile_ranges",
            ],
        );
        use wgpu::BufferUsages as U;
        let storage = U::STORAGE | U::COPY_DST | U::COPY_SRC;
        let buffer = |label| GrowBuffer::new(device, label, storage);
        let staging = |label| GrowBuffer::new(device, label, U::MAP_READ | U::COPY_DST);
        Self {
            gpu: gpu.clone(),
            count_tiles,
            depth_counts,
            emit,
            finish,
            tile_ranges,
            sort: GpuRadixSort::new(gpu),
            params: GrowBuffer::new(device, "bin_params", U::UNIFORM | U::COPY_DST),
            splats: buffer("splat_boxes"),
            rects: buffer("tile_rects"),
            splat_offsets: buffer("splat_offsets"),
            depth: SortBuffers::new(device),
            depth_result: 0,
            depth_offsets: buffer("depth_offsets"),
            tiles: SortBuffers::new(device),
            entry_splat: buffer("entry_splat"),
            sorted_splats: buffer("sorted_splats"),
            sorted_position: buffer("sorted_position"),
            tile_offsets: buffer("tile_offsets"),
            count_staging: staging("entry_count"),
            staging: staging("bin_staging"),
            host_boxes: Vec::new(),
            host_values: Vec::new(),
            splat_count: 0,
            entries: 0,
            tiles_xy: (0, 0),
        }
    }

    /// Number of (tile, splat) pairs of the last [`GpuBinner::bin`].
    pub fn entry_count(&self) -> usize {
        self.entries as usize
    }

    /// Tile columns and rows of the last [`GpuBinner::bin`]: ⌈width / 16⌉, ⌈height / 16⌉.
    pub fn tiles(&self) -> (usize, usize) {
        (self.tiles_xy.0 as usize, self.tiles_xy.1 as usize)
    }

    /// Bins `splats` for an image of `width × height` pixels. The work runs on the GPU with
    /// one wait in the middle, to read back the number of entries and size their buffers.
    pub fn bin(&mut self, splats: &[Splat], width: usize, height: usize) -> Result<(), GpuError> {
        self.host_boxes.clear();
        self.host_boxes.extend(splats.iter().map(SplatBox::from));
        self.splats.upload(&self.gpu, &self.host_boxes);
        self.run(splats.len() as u32, width, height)
    }

    /// [`GpuBinner::bin`] for splats already in [`SplatBox`] form.
    pub fn bin_boxes(
        &mut self,
        boxes: &[SplatBox],
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        self.splats.upload(&self.gpu, boxes);
        self.run(boxes.len() as u32, width, height)
    }

    /// The [`SplatBox`] buffer, sized for `count` boxes, for a kernel to fill before
    /// [`GpuBinner::bin_resident`].
    pub(super) fn boxes_for(&mut self, count: usize) -> &wgpu::Buffer {
        self.splats
            .reserve(&self.gpu.device, (count * size_of::<SplatBox>()) as u64);
        &self.splats.buffer
    }

    /// [`GpuBinner::bin`] of the `count` boxes a kernel wrote into [`GpuBinner::boxes_for`].
    pub(super) fn bin_resident(
        &mut self,
        count: usize,
        width: usize,
        height: usize,
    ) -> Result<(), GpuError> {
        self.run(count as u32, width, height)
    }

    fn run(&mut self, n: u32, width: usize, height: usize) -> Result<(), GpuError> {
        let gpu = self.gpu.clone();
        let device = &gpu.device;
        let tiles_x = width.div_ceil(TILE) as u32;
        let tiles_y = height.div_ceil(TILE) as u32;
        let tile_count = tiles_x * tiles_y;
        self.tiles_xy = (tiles_x, tiles_y);
        self.splat_count = n;
        self.params.upload(
            &gpu,
            &[BinParams {
                tiles_x,
                tiles_y,
                splat_count: n,
                tile_count,
            }],
        );
        let offsets_bytes = 4 * (n as u64 + 1);
        self.splat_offsets.reserve(device, offsets_bytes);
        self.tile_offsets
            .reserve(device, 4 * (tile_count as u64 + 1));

        // Tile counts, splat offsets, the depth order and the offsets in depth order.
        if n == 0 {
            gpu.queue
                .write_buffer(&self.splat_offsets.buffer, 0, &[0; 4]);
            self.entries = 0;
        } else {
            self.rects.reserve(device, 16 * n as u64);
            self.depth.reserve(device, n);
            self.depth_offsets.reserve(device, offsets_bytes);
            self.count_staging.reserve(device, 4);
            self.sort.prepare(n);
            self.sort.scan.prepare(n + 1);
            let bytes = 4 * n as u64;
            let mut encoder = device.create_command_encoder(&Default::default());
            let params = || self.params.buffer.as_entire_binding();
            let offsets = || storage(&self.splat_offsets.buffer, offsets_bytes);
            let group = bind(
                device,
                &self.count_tiles,
                vec![
                    (0, params()),
                    (1, storage(&self.splats.buffer, 24 * n as u64)),
                    (2, storage(&self.rects.buffer, 16 * n as u64)),
                    (3, offsets()),
                    (4, storage(&self.depth.keys[0].buffer, bytes)),
                    (5, storage(&self.depth.values[0].buffer, bytes)),
                ],
            );
            dispatch(&mut encoder, &self.count_tiles, &group, groups_for(n + 1));
            self.sort
                .scan
                .encode(&mut encoder, &self.splat_offsets.buffer, n + 1);
            self.depth_result = self.sort.encode(&mut encoder, &self.depth, n, 32);
            let group = bind(
                device,
                &self.depth_counts,
                vec![
                    (0, params()),
                    (3, offsets()),
                    (
                        6,
                        storage(&self.depth.values[self.depth_result].buffer, bytes),
                    ),
                    (7, storage(&self.depth_offsets.buffer, offsets_bytes)),
                ],
            );
            dispatch(&mut encoder, &self.depth_counts, &group, groups_for(n + 1));
            self.sort
                .scan
                .encode(&mut encoder, &self.depth_offsets.buffer, n + 1);
            encoder.copy_buffer_to_buffer(
                &self.splat_offsets.buffer,
                bytes,
                &self.count_staging.buffer,
                0,
                4,
            );
            gpu.queue.submit([encoder.finish()]);
            gpu.read_back(&self.count_staging.buffer, 4, &mut self.host_values)?;
            self.entries = self.host_values[0];
        }

        // Entries in depth order, sorted by tile; the per-tile ranges.
        let e = self.entries;
        let entry_bytes = 4 * e as u64;
        self.sorted_splats.reserve(device, entry_bytes);
        self.sorted_position.reserve(device, entry_bytes);
        let mut encoder = device.create_command_encoder(&Default::default());
        if e == 0 {
            encoder.clear_buffer(
                &self.tile_offsets.buffer,
                0,
                Some(4 * (tile_count as u64 + 1)),
            );
        } else {
            self.tiles.reserve(device, e);
            self.entry_splat.reserve(device, entry_bytes);
            self.sort.prepare(e);
            let params = || self.params.buffer.as_entire_binding();
            let group = bind(
                device,
                &self.emit,
                vec![
                    (0, params()),
                    (2, storage(&self.rects.buffer, 16 * n as u64)),
                    (3, storage(&self.splat_offsets.buffer, offsets_bytes)),
                    (
                        6,
                        storage(&self.depth.values[self.depth_result].buffer, 4 * n as u64),
                    ),
                    (7, storage(&self.depth_offsets.buffer, offsets_bytes)),
                    (8, storage(&self.tiles.keys[0].buffer, entry_bytes)),
                    (9, storage(&self.tiles.values[0].buffer, entry_bytes)),
                    (10, storage(&self.entry_splat.buffer, entry_bytes)),
                ],
            );
            dispatch(&mut encoder, &self.emit, &group, groups_for(n));
            let tile_bits = u32::BITS - (tile_count - 1).leading_zeros();
            let sorted = self.sort.encode(&mut encoder, &self.tiles, e, tile_bits);
            let group = bind(
                device,
                &self.finish,
                vec![
                    (10, storage(&self.entry_splat.buffer, entry_bytes)),
                    (12, storage(&self.tiles.values[sorted].buffer, entry_bytes)),
                    (13, storage(&self.sorted_splats.buffer, entry_bytes)),
                    (14, storage(&self.sorted_position.buffer, entry_bytes)),
                ],
            );
            dispatch(&mut encoder, &self.finish, &group, groups_for(e));
            let group = bind(
                device,
                &self.tile_ranges,
                vec![
                    (0, params()),
                    (11, storage(&self.tiles.keys[sorted].buffer, entry_bytes)),
                    (15, self.tile_offsets.binding()),
                ],
            );
            dispatch(
                &mut encoder,
                &self.tile_ranges,
                &group,
                groups_for(tile_count + 1),
            );
        }
        gpu.queue.submit([encoder.finish()]);
        Ok(())
    }

    /// Copies the result of the last [`GpuBinner::bin`] back into `out`.
    pub fn read(&mut self, out: &mut BinReadback) -> Result<(), GpuError> {
        let (tx, ty) = self.tiles_xy;
        let tiles = (tx * ty + 1) as u64;
        let (n, e) = (self.splat_count as u64 + 1, self.entries as u64);
        let parts: [(&wgpu::Buffer, u64); 4] = [
            (&self.tile_offsets.buffer, tiles),
            (&self.sorted_splats.buffer, e),
            (&self.splat_offsets.buffer, n),
            (&self.sorted_position.buffer, e),
        ];
        let total = 4 * parts.iter().map(|p| p.1).sum::<u64>();
        self.staging.reserve(&self.gpu.device, total);
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        let mut at = 0;
        for (buffer, len) in parts {
            if len > 0 {
                encoder.copy_buffer_to_buffer(buffer, 0, &self.staging.buffer, at, 4 * len);
            }
            at += 4 * len;
        }
        self.gpu.queue.submit([encoder.finish()]);
        self.gpu
            .read_back(&self.staging.buffer, total, &mut self.host_values)?;
        let mut rest = &self.host_values[..];
        for (out, len) in [
            (&mut out.tile_offsets, tiles),
            (&mut out.sorted_splats, e),
            (&mut out.splat_offsets, n),
            (&mut out.sorted_position, e),
        ] {
            let (part, tail) = rest.split_at(len as usize);
            out.clear();
            out.extend_from_slice(part);
            rest = tail;
        }
        Ok(())
    }

    /// The GPU buffers of the last [`GpuBinner::bin`].
    pub fn buffers(&self) -> BinBuffers<'_> {
        BinBuffers {
            tile_offsets: &self.tile_offsets.buffer,
            sorted_splats: &self.sorted_splats.buffer,
            splat_offsets: &self.splat_offsets.buffer,
            sorted_position: &self.sorted_position.buffer,
            splats: &self.splats.buffer,
        }
    }
}
