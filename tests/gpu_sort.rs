//! The GPU prefix sum, radix sort and tile binning equal their CPU references: the scan a
//! sequential sum, the sort a stable sort, the binning `TileBins::build` entry for entry.

#[path = "common/gpu.rs"]
mod gpu;

use std::time::Instant;

use glam::Vec2;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tadgs::gpu::{BinReadback, GpuBinner, GpuRadixSort, GpuScan};
use tadgs::raster::{Splat, TileBins};

/// Exclusive prefix sums for lengths around the block size (2048) and its square (three
/// levels of block sums), with values large enough to wrap around u32.
#[test]
fn gpu_scan_equals_sequential_sums() {
    let Some(ctx) = gpu::gpu_context() else {
        return;
    };
    let mut scan = GpuScan::new(&ctx);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut out = Vec::new();
    for len in [0, 1, 255, 2047, 2048, 2049, 300_000, 2048 * 2048 + 5] {
        let big = len < 3000;
        let values: Vec<u32> = (0..len)
            .map(|_| {
                if big {
                    rng.random()
                } else {
                    rng.random_range(0..100)
                }
            })
            .collect();
        let start = Instant::now();
        let total = scan.exclusive_scan(&values, &mut out).unwrap();
        eprintln!("scan of {len} values: {:?}", start.elapsed());
        let mut sum = 0u32;
        for (i, (&v, &o)) in values.iter().zip(&out).enumerate() {
            assert_eq!(o, sum, "length {len}: prefix {i}");
            sum = sum.wrapping_add(v);
        }
        assert_eq!(out.len(), len);
        assert_eq!(total, sum, "length {len}: total");
    }
}

/// Sorting keys of `bits` bits equals Rust's stable sort: keys with many duplicates (so
/// stability shows), bit counts that are and are not multiples of the 4-bit digit, counts
/// from 0 to over a million.
#[test]
fn gpu_radix_sort_equals_stable_sort() {
    let Some(ctx) = gpu::gpu_context() else {
        return;
    };
    let mut sort = GpuRadixSort::new(&ctx);
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let (mut keys_out, mut values_out) = (Vec::new(), Vec::new());
    for (n, bits, distinct) in [
        (0, 32, 1),
        (1, 32, 1),
        (100, 7, 50),
        (5000, 32, 1000),
        (70_000, 13, 8192),
        (1_200_000, 32, 100_000),
    ] {
        // Random keys of `bits` bits from `distinct` values spread over the range.
        let mask = if bits >= 32 {
            u32::MAX
        } else {
            (1 << bits) - 1
        };
        let keys: Vec<u32> = (0..n)
            .map(|_| {
                rng.random_range(0..distinct as u32)
                    .wrapping_mul(2_654_435_761)
                    & mask
            })
            .collect();
        let values: Vec<u32> = (0..n as u32).collect();
        let start = Instant::now();
        sort.sort(&keys, &values, bits, &mut keys_out, &mut values_out)
            .unwrap();
        eprintln!(
            "radix sort of {n} pairs on {bits} bits: {:?}",
            start.elapsed()
        );
        let mut expected: Vec<(u32, u32)> = keys.iter().copied().zip(values).collect();
        expected.sort_by_key(|&(k, _)| k);
        assert_eq!(keys_out.len(), n);
        for (i, (&(k, v), (&gk, &gv))) in expected
            .iter()
            .zip(keys_out.iter().zip(&values_out))
            .enumerate()
        {
            assert_eq!((gk, gv), (k, v), "{n} pairs, {bits} bits: position {i}");
        }
    }
}

/// Random splats over a `width × height` image: from sub-tile to a third of the image,
/// partly off screen, some invisible, depths drawn from `depth_levels` values so that many
/// are equal (ties are broken by splat index).
fn random_splats(
    rng: &mut ChaCha8Rng,
    n: usize,
    width: f32,
    height: f32,
    depth_levels: u32,
) -> Vec<Splat> {
    (0..n)
        .map(|_| {
            let big = rng.random_bool(0.05);
            let limit = if big { width.min(height) / 3.0 } else { 24.0 };
            Splat {
                mean2d: Vec2::new(
                    rng.random_range(-40.0..width + 40.0),
                    rng.random_range(-40.0..height + 40.0),
                ),
                depth: 0.5 + rng.random_range(0..depth_levels) as f32 * 0.37,
                extent: Vec2::new(rng.random_range(0.0..limit), rng.random_range(0.0..limit)),
                visible: rng.random_bool(0.9),
                ..Default::default()
            }
        })
        .collect()
}

/// Splats whose box edges fall exactly on tile boundaries, with zero extents and extents that
/// end at the image border.
fn edge_splats(width: f32, height: f32) -> Vec<Splat> {
    let mut splats = Vec::new();
    for (i, x) in [0.0, 16.0, 31.999, 32.0, width - 16.0, width]
        .iter()
        .enumerate()
    {
        for (j, e) in [0.0, 8.0, 16.0, 0.5].iter().enumerate() {
            splats.push(Splat {
                mean2d: Vec2::new(*x, height - x.min(height)),
                extent: Vec2::new(*e, 16.0 - e),
                depth: 1.0 + (i * j % 3) as f32,
                visible: true,
                ..Default::default()
            });
        }
    }
    splats
}

/// Tile binning on the GPU equals `TileBins::build`: the per-tile ranges, every tile's splats
/// in the same order (depth, then splat index), the per-splat entry offsets and the sorted
/// position of every entry. Image sizes that are and are not multiples of the tile, a single
/// tile, populations from 0 to 60 000 splats (about 780 000 entries).
#[test]
fn gpu_binning_equals_cpu_bins() {
    let Some(ctx) = gpu::gpu_context() else {
        return;
    };
    let mut binner = GpuBinner::new(&ctx);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut cpu = TileBins::default();
    let mut out = BinReadback::default();
    let mut cases: Vec<(usize, usize, Vec<Splat>)> = vec![
        (64, 48, Vec::new()),
        (16, 16, random_splats(&mut rng, 50, 16.0, 16.0, 5)),
        (77, 53, random_splats(&mut rng, 1, 77.0, 53.0, 1)),
        (100, 70, edge_splats(100.0, 70.0)),
        (160, 120, random_splats(&mut rng, 3000, 160.0, 120.0, 20)),
        (33, 200, random_splats(&mut rng, 500, 33.0, 200.0, 3)),
        (0, 10, random_splats(&mut rng, 10, 1.0, 10.0, 3)),
    ];
    // Invisible everywhere: no entries at all.
    let mut hidden = random_splats(&mut rng, 100, 64.0, 64.0, 4);
    hidden.iter_mut().for_each(|s| s.visible = false);
    cases.push((64, 64, hidden));
    cases.push((
        1280,
        720,
        random_splats(&mut rng, 60_000, 1280.0, 720.0, 5000),
    ));
    for (width, height, splats) in cases {
        cpu.build(&splats, width, height);
        let start = Instant::now();
        binner.bin(&splats, width, height).unwrap();
        binner.read(&mut out).unwrap();
        let n = splats.len();
        eprintln!(
            "binning {n} splats, {width}×{height}: {} entries in {:?}",
            binner.entry_count(),
            start.elapsed()
        );
        let case = format!("{width}×{height}, {n} splats");
        assert_eq!(binner.tiles(), (cpu.tiles_x, cpu.tiles_y), "{case}");
        assert_eq!(binner.entry_count(), cpu.entry_count(), "{case}");
        assert_eq!(out.tile_offsets, cpu.tile_offsets, "{case}: tile offsets");
        for t in 0..cpu.tiles_x * cpu.tiles_y {
            let range = cpu.tile_range(t);
            assert_eq!(
                out.sorted_splats[range.clone()],
                cpu.sorted_splats[range],
                "{case}: splats of tile {t}"
            );
        }
        assert_eq!(
            out.splat_offsets,
            cpu.splat_offsets(),
            "{case}: splat offsets"
        );
        assert_eq!(
            out.sorted_position,
            cpu.sorted_position(),
            "{case}: sorted positions"
        );
    }
}

/// Dispatches laid out as 2D grids (as beyond 65 535 workgroups) give the same results: the
/// grid width is lowered to 3 workgroups so that small inputs need several rows, most with
/// workgroups past the end. Scan, sort and binning are checked against their references.
#[test]
fn two_dimensional_dispatches_give_the_same_results() {
    let Some(ctx) = gpu::gpu_context() else {
        return;
    };
    // Process-wide: the other tests of this file may run with it too, and must pass either way.
    tadgs::gpu::set_max_dispatch_width(3);
    let mut rng = ChaCha8Rng::seed_from_u64(4);

    let values: Vec<u32> = (0..100_000).map(|_| rng.random_range(0..1000)).collect();
    let mut out = Vec::new();
    let total = GpuScan::new(&ctx)
        .exclusive_scan(&values, &mut out)
        .unwrap();
    let mut sum = 0;
    for (i, (&v, &o)) in values.iter().zip(&out).enumerate() {
        assert_eq!(o, sum, "prefix {i}");
        sum += v;
    }
    assert_eq!(total, sum);

    let keys: Vec<u32> = (0..30_000).map(|_| rng.random_range(0..5000)).collect();
    let ids: Vec<u32> = (0..30_000).collect();
    let (mut sorted_keys, mut sorted_ids) = (Vec::new(), Vec::new());
    GpuRadixSort::new(&ctx)
        .sort(&keys, &ids, 13, &mut sorted_keys, &mut sorted_ids)
        .unwrap();
    let mut expected: Vec<(u32, u32)> = keys.iter().copied().zip(ids).collect();
    expected.sort_by_key(|&(k, _)| k);
    let got: Vec<(u32, u32)> = sorted_keys.into_iter().zip(sorted_ids).collect();
    assert!(got == expected, "2D sort differs from the stable sort");

    let splats = random_splats(&mut rng, 3000, 160.0, 120.0, 20);
    let mut cpu = TileBins::default();
    cpu.build(&splats, 160, 120);
    let mut binner = GpuBinner::new(&ctx);
    binner.bin(&splats, 160, 120).unwrap();
    let mut bins = BinReadback::default();
    binner.read(&mut bins).unwrap();
    assert_eq!(bins.tile_offsets, cpu.tile_offsets);
    assert_eq!(bins.sorted_splats, cpu.sorted_splats);
    assert_eq!(bins.splat_offsets, cpu.splat_offsets());
    assert_eq!(bins.sorted_position, cpu.sorted_position());
    tadgs::gpu::set_max_dispatch_width(65_535);
}
