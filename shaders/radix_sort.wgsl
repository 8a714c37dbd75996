// One pass of a stable LSD radix sort of (u32 key, u32 value) pairs on a 4-bit digit
// (appended to scan_common.wgsl). Portable: u32 atomics in workgroup memory only, no subgroup
// operations. A pass is `histogram_pass` (digit counts per block of BLOCK keys, stored
// digit-major: histogram[digit · blocks + block]), an exclusive scan of `histogram` (scan.wgsl),
// and `scatter_pass`, which moves each key to its digit's offset plus its stable rank among the
// block's keys of that digit. Each invocation owns ITEMS consecutive keys, so ranks follow the
// input order and equal keys keep it.

struct SortPass {
    // The digit is (key >> shift) & 15.
    shift: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const RADIX: u32 = 16u;

@group(0) @binding(0) var<uniform> pass_info: SortPass;
@group(0) @binding(1) var<storage, read> keys_in: array<u32>;
@group(0) @binding(2) var<storage, read> vals_in: array<u32>;
@group(0) @binding(3) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(4) var<storage, read_write> vals_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> histogram: array<u32>;

var<workgroup> digit_counts: array<atomic<u32>, RADIX>;
// Digit-major table: positions[digit · THREADS + invocation].
var<workgroup> positions: array<u32, 4096>;

fn digit_of(key: u32) -> u32 {
    return (key >> pass_info.shift) & (RADIX - 1u);
}

@compute @workgroup_size(256)
fn histogram_pass(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let block = group_index(wid, groups);
    let n = arrayLength(&keys_in);
    let blocks = (n + BLOCK - 1u) / BLOCK;
    if block >= blocks {
        return;
    }
    if lid < RADIX {
        atomicStore(&digit_counts[lid], 0u);
    }
    workgroupBarrier();
    var counts: array<u32, RADIX>;
    for (var i = 0u; i < ITEMS; i++) {
        let k = block * BLOCK + i * THREADS + lid;
        if k < n {
            counts[digit_of(keys_in[k])] += 1u;
        }
    }
    for (var d = 0u; d < RADIX; d++) {
        if counts[d] > 0u {
            atomicAdd(&digit_counts[d], counts[d]);
        }
    }
    workgroupBarrier();
    if lid < RADIX {
        histogram[lid * blocks + block] = atomicLoad(&digit_counts[lid]);
    }
}

@compute @workgroup_size(256)
fn scatter_pass(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let block = group_index(wid, groups);
    let n = arrayLength(&keys_in);
    let blocks = (n + BLOCK - 1u) / BLOCK;
    if block >= blocks {
        return;
    }
    let first = block * BLOCK + lid * ITEMS;
    var keys: array<u32, ITEMS>;
    var counts: array<u32, RADIX>;
    for (var i = 0u; i < ITEMS; i++) {
        let k = first + i;
        if k < n {
            keys[i] = keys_in[k];
            counts[digit_of(keys[i])] += 1u;
        }
    }
    for (var d = 0u; d < RADIX; d++) {
        positions[d * THREADS + lid] = counts[d];
    }
    workgroupBarrier();
    // Exclusive scan of the digit-major table: where each invocation's keys of each digit start
    // in the block sorted by digit.
    var total = 0u;
    for (var j = 0u; j < RADIX; j++) {
        let x = positions[lid * RADIX + j];
        positions[lid * RADIX + j] = total;
        total += x;
    }
    let scan = workgroup_scan(lid, total);
    for (var j = 0u; j < RADIX; j++) {
        positions[lid * RADIX + j] += scan.x;
    }
    workgroupBarrier();
    for (var d = 0u; d < RADIX; d++) {
        counts[d] = 0u;
    }
    for (var i = 0u; i < ITEMS; i++) {
        let k = first + i;
        if k < n {
            let d = digit_of(keys[i]);
            // Rank among the block's keys of digit d, in input order.
            let rank = positions[d * THREADS + lid] + counts[d] - positions[d * THREADS];
            counts[d] += 1u;
            let dst = histogram[d * blocks + block] + rank;
            keys_out[dst] = keys[i];
            vals_out[dst] = vals_in[k];
        }
    }
}
