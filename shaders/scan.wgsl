// Exclusive prefix sum of u32 values in place, in blocks of BLOCK values (appended to
// scan_common.wgsl). `scan_blocks` scans each block and writes the block's total to
// `block_sums`; the host scans `block_sums` the same way (one level per factor of 2048) and
// `add_block_sums` adds each block's scanned offset to its values.

@group(0) @binding(0) var<storage, read_write> data: array<u32>;
@group(0) @binding(1) var<storage, read_write> block_sums: array<u32>;

// The block, staged so that global memory is read and written in consecutive addresses.
var<workgroup> staged: array<u32, BLOCK>;

@compute @workgroup_size(256)
fn scan_blocks(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let block = group_index(wid, groups);
    let n = arrayLength(&data);
    if block >= (n + BLOCK - 1u) / BLOCK {
        return;
    }
    let start = block * BLOCK;
    for (var i = 0u; i < ITEMS; i++) {
        let k = start + i * THREADS + lid;
        var x = 0u;
        if k < n {
            x = data[k];
        }
        staged[i * THREADS + lid] = x;
    }
    workgroupBarrier();
    // Each invocation scans ITEMS consecutive values; the workgroup scans the invocations' sums.
    var total = 0u;
    for (var i = 0u; i < ITEMS; i++) {
        let j = lid * ITEMS + i;
        let x = staged[j];
        staged[j] = total;
        total += x;
    }
    let scan = workgroup_scan(lid, total);
    for (var i = 0u; i < ITEMS; i++) {
        staged[lid * ITEMS + i] += scan.x;
    }
    workgroupBarrier();
    for (var i = 0u; i < ITEMS; i++) {
        let k = start + i * THREADS + lid;
        if k < n {
            data[k] = staged[i * THREADS + lid];
        }
    }
    if lid == 0u && block < arrayLength(&block_sums) {
        block_sums[block] = scan.y;
    }
}

@compute @workgroup_size(256)
fn add_block_sums(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let block = group_index(wid, groups);
    if block >= arrayLength(&block_sums) {
        return;
    }
    let offset = block_sums[block];
    let n = arrayLength(&data);
    for (var i = 0u; i < ITEMS; i++) {
        let k = block * BLOCK + i * THREADS + lid;
        if k < n {
            data[k] += offset;
        }
    }
}
