
// Fast path where the adapter offers SHADER_FLOAT32_ATOMIC and SUBGROUP: each subgroup adds
// its pixels' shares (subgroupAdd), and its first invocation adds the non-zero sums straight
// into the splat's gradient, with no workgroup barriers and no reduction pass. The order of
// the additions varies from run to run.

// Per splat: the gradient fields (zeroed before the pass).
@group(0) @binding(7) var<storage, read_write> splat_grads: array<atomic<f32>>;

// Called by every invocation of the workgroup (subgroup operations need them all).
fn add_shares(li: u32, entry: u32, values: array<f32, FIELDS>) {
    // The nine sums with constant indices, and the entry's splat read by the one invocation
    // that adds them: an array indexed in a loop and a read by every invocation cost more.
    var sums = array<f32, FIELDS>(
        subgroupAdd(values[0]), subgroupAdd(values[1]), subgroupAdd(values[2]),
        subgroupAdd(values[3]), subgroupAdd(values[4]), subgroupAdd(values[5]),
        subgroupAdd(values[6]), subgroupAdd(values[7]), subgroupAdd(values[8]),
    );
    if subgroupExclusiveAdd(1u) == 0u {
        let base = FIELDS * sorted_splats[entry];
        for (var field = 0u; field < FIELDS; field++) {
            // Skip exact zeros by their bits: a float comparison `sum != 0.0` is ordered, so a
            // NaN sum would be skipped too and the gradient check would never see it.
            if (bitcast<u32>(sums[field]) << 1u) != 0u {
                atomicAdd(&splat_grads[base + field], sums[field]);
            }
        }
    }
}
