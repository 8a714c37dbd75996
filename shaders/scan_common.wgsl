// Shared by the prefix-sum (scan.wgsl) and radix-sort (radix_sort.wgsl) kernels: block
// geometry and a workgroup-wide exclusive prefix sum in workgroup memory. Portable: no
// subgroup operations, no atomics.

const THREADS: u32 = 256u;
// Values per invocation; a workgroup handles one block of THREADS · ITEMS values.
const ITEMS: u32 = 8u;
const BLOCK: u32 = 2048u;

var<workgroup> scan_sums: array<u32, THREADS>;

// Flat index of this workgroup in a dispatch laid out as a 2D grid (x wraps at the grid width).
fn group_index(wid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return wid.y * groups.x + wid.x;
}

// Exclusive prefix sum of `value` over the workgroup's invocations (Hillis–Steele in workgroup
// memory): x is this invocation's prefix, y the workgroup's total. Every invocation must call it.
fn workgroup_scan(lid: u32, value: u32) -> vec2<u32> {
    scan_sums[lid] = value;
    workgroupBarrier();
    for (var offset = 1u; offset < THREADS; offset <<= 1u) {
        var add = 0u;
        if lid >= offset {
            add = scan_sums[lid - offset];
        }
        workgroupBarrier();
        scan_sums[lid] += add;
        workgroupBarrier();
    }
    let result = vec2(scan_sums[lid] - value, scan_sums[THREADS - 1u]);
    // The next call may overwrite scan_sums only once everyone has read it.
    workgroupBarrier();
    return result;
}
