
// Fast path where the adapter offers SHADER_FLOAT32_ATOMIC and SUBGROUP: each subgroup adds
// its pixels' shares (subgroupAdd), and its first invocation adds the non-zero sums straight
// into the splat's gradient, with no workgroup barriers and no reduction pass. The order of
// the additions varies from run to run.

// Per splat: the gradient fields (zeroed before the pass).
@group(0) @binding(7) var<storage, read_write> splat_grads: array<atomic<f32>>;

// Called by every invocation of the workgroup (subgroup operations need them all).
fn add_shares(li: u32, entry: u32, values: array<f32, FIELDS>) {
    var share = values; // a variable, so it can be indexed dynamically
    let first = subgroupExclusiveAdd(1u) == 0u;
    let base = FIELDS * sorted_splats[entry];
    for (var field = 0u; field < FIELDS; field++) {
        let sum = subgroupAdd(share[field]);
        // Skip exact zeros by their bits: a float comparison `sum != 0.0` is ordered, so a
        // NaN sum would be skipped too and the gradient check would never see it.
        if first && (bitcast<u32>(sum) << 1u) != 0u {
            atomicAdd(&splat_grads[base + field], sum);
        }
    }
}
