// One pass of a stable LSD radix sort of (u32 key, u32 value) pairs on a 4-bit digit
// (appended to scan_common.wgsl). Portable: u32 atomics in workgroup memory only, no subgroup
// operations. A pass is `histogram_pass` (digit counts per block of BLOCK keys, stored
// digit-major: histogram[digit · blocks + block]), an exclusive scan of `histogram` (scan.wgsl),
// and `scatter_pass`, which moves each key to its digit's offset plus its stable rank among the
// block's keys of that digit. Each invocation owns ITEMS consecutive keys, so ranks follow the
// input order and equal keys keep it.
//
// Written for lavapipe as much as for a GPU: there every access of storage or workgroup memory
// at a per-invocation address is a loop over the SIMD lanes (one loop for all components of a
// vector), so keys and values are read as quads, and an invocation's digit counts are packed
// into two words rather than an array indexed by the digit.

struct SortPass {
    // The digit is (key >> shift) & 15.
    shift: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct SortSize {
    // Pairs sorted.
    count: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

const RADIX: u32 = 16u;
// An invocation's ITEMS keys as quads.
const QUADS: u32 = ITEMS / 4u;

@group(0) @binding(0) var<uniform> pass_info: SortPass;
// Bound rounded up to whole quads; elements from `size.count` on are not read as keys.
@group(0) @binding(1) var<storage, read> keys_in: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read> vals_in: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(4) var<storage, read_write> vals_out: array<u32>;
@group(0) @binding(5) var<storage, read_write> histogram: array<u32>;
@group(0) @binding(6) var<uniform> size: SortSize;

// The block's digit counts, two digits per word (16 bits each: at most BLOCK = 2048 keys).
var<workgroup> digit_pairs: array<atomic<u32>, 8>;
// Digit-major table: element digit · THREADS + invocation, four elements per quad.
var<workgroup> positions: array<vec4<u32>, 1024>;
// Where digit d's keys of this block go: their offset over all blocks less their start in the
// block.
var<workgroup> digit_base: array<u32, RADIX>;

fn digit_of(key: u32) -> u32 {
    return (key >> pass_info.shift) & (RADIX - 1u);
}

// An invocation's digit counts, four bits per digit (ITEMS = 8 keys at most, so a count fits):
// digits 0–7 in x, 8–15 in y.
fn add_digit(counts: vec2<u32>, digit: u32) -> vec2<u32> {
    let one = 1u << (4u * (digit & 7u));
    return counts + select(vec2(one, 0u), vec2(0u, one), digit >= 8u);
}

// `counts` with the digits of the quad of keys that starts at key `at`, those below `n`.
fn add_quad(counts: vec2<u32>, keys: vec4<u32>, at: u32, n: u32) -> vec2<u32> {
    var out = counts;
    for (var c = 0u; c < 4u; c++) {
        if at + c < n {
            out = add_digit(out, digit_of(keys[c]));
        }
    }
    return out;
}

fn count_of(counts: vec2<u32>, digit: u32) -> u32 {
    return (select(counts.x, counts.y, digit >= 8u) >> (4u * (digit & 7u))) & 15u;
}

fn table(i: u32) -> u32 {
    return positions[i / 4u][i % 4u];
}

// The number of blocks of BLOCK keys, or 0 when this workgroup has no block to sort.
fn blocks_with(block: u32) -> u32 {
    let blocks = (size.count + BLOCK - 1u) / BLOCK;
    return select(0u, blocks, block < blocks);
}

@compute @workgroup_size(256)
fn histogram_pass(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let block = group_index(wid, groups);
    let blocks = blocks_with(block);
    if blocks == 0u {
        return;
    }
    if lid < RADIX / 2u {
        atomicStore(&digit_pairs[lid], 0u);
    }
    workgroupBarrier();
    let n = size.count;
    let first = block * BLOCK + lid * ITEMS;
    var counts = vec2(0u);
    for (var q = 0u; q < QUADS; q++) {
        let at = first + 4u * q;
        if at < n {
            counts = add_quad(counts, keys_in[at / 4u], at, n);
        }
    }
    for (var p = 0u; p < RADIX / 2u; p++) {
        let pair = count_of(counts, 2u * p) | (count_of(counts, 2u * p + 1u) << 16u);
        if pair > 0u {
            atomicAdd(&digit_pairs[p], pair);
        }
    }
    workgroupBarrier();
    if lid < RADIX {
        let pair = atomicLoad(&digit_pairs[lid / 2u]);
        histogram[lid * blocks + block] = (pair >> (16u * (lid & 1u))) & 0xffffu;
    }
}

@compute @workgroup_size(256)
fn scatter_pass(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let block = group_index(wid, groups);
    let blocks = blocks_with(block);
    if blocks == 0u {
        return;
    }
    let n = size.count;
    let first = block * BLOCK + lid * ITEMS;
    var keys: array<vec4<u32>, QUADS>;
    var vals: array<vec4<u32>, QUADS>;
    var counts = vec2(0u);
    for (var q = 0u; q < QUADS; q++) {
        let at = first + 4u * q;
        if at < n {
            keys[q] = keys_in[at / 4u];
            vals[q] = vals_in[at / 4u];
            counts = add_quad(counts, keys[q], at, n);
        }
    }
    for (var d = 0u; d < RADIX; d++) {
        let i = d * THREADS + lid;
        positions[i / 4u][i % 4u] = count_of(counts, d);
    }
    workgroupBarrier();
    // Exclusive scan of the digit-major table: invocation lid owns its quads 4·lid .. 4·lid + 3,
    // then adds what the invocations before it hold.
    var scanned: array<vec4<u32>, 4>;
    var total = 0u;
    for (var j = 0u; j < 4u; j++) {
        let x = positions[4u * lid + j];
        scanned[j] = vec4(total, total + x.x, total + x.x + x.y, total + x.x + x.y + x.z);
        total += x.x + x.y + x.z + x.w;
    }
    let before = workgroup_scan(lid, total).x;
    for (var j = 0u; j < 4u; j++) {
        positions[4u * lid + j] = scanned[j] + before;
    }
    workgroupBarrier();
    if lid < RADIX {
        digit_base[lid] = histogram[lid * blocks + block] - table(lid * THREADS);
    }
    workgroupBarrier();
    // Each key's rank among the block's keys of its digit, in input order.
    var seen = vec2(0u);
    for (var q = 0u; q < QUADS; q++) {
        for (var c = 0u; c < 4u; c++) {
            if first + 4u * q + c < n {
                let key = keys[q][c];
                let d = digit_of(key);
                let dst = digit_base[d] + table(d * THREADS + lid) + count_of(seen, d);
                seen = add_digit(seen, d);
                keys_out[dst] = key;
                vals_out[dst] = vals[q][c];
            }
        }
    }
}
