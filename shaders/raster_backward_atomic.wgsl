
// Fast path where the adapter offers SHADER_FLOAT32_ATOMIC and SUBGROUP: each subgroup adds
// its pixels' shares (subgroupAdd), and its first invocation adds the non-zero sums straight
// into the splat's gradient, with no workgroup barriers and no reduction pass. The order of
// the additions varies from run to run.

// The entries of one word of a batch that a subgroup visits: those before the last contributor
// of any of its pixels (`useful`) that can be drawn in one of its pixels' segments; every other
// entry would add zeros.
fn entry_candidates(own: u32, word: u32, useful: u32) -> u32 {
    return lane_candidates(own) & useful;
}

// The subgroup's own bound on the entries worth visiting, below the workgroup's.
fn contributor_bound(contributor: u32, workgroup_bound: u32) -> u32 {
    return subgroupMax(contributor);
}

// Per splat: the gradient fields (zeroed before the pass).
@group(0) @binding(7) var<storage, read_write> splat_grads: array<atomic<f32>>;

// Called by every invocation of the subgroup (subgroup operations need them all).
fn add_shares(li: u32, entry: u32, values: array<f32, FIELDS>) {
    // Most visited entries draw at none of the subgroup's pixels (they fall outside the
    // ellipse inside the box): one vote spares the nine sums. By the bits again, so that a NaN
    // share is added.
    let bits = bitcast<u32>(values[0]) | bitcast<u32>(values[1]) | bitcast<u32>(values[2])
        | bitcast<u32>(values[3]) | bitcast<u32>(values[4]) | bitcast<u32>(values[5])
        | bitcast<u32>(values[6]) | bitcast<u32>(values[7]) | bitcast<u32>(values[8]);
    if !subgroupAny((bits << 1u) != 0u) {
        return;
    }
    // The nine sums with constant indices, and the entry's splat read by the one invocation
    // that adds them: an array indexed in a loop and a read by every invocation cost more.
    var sums = array<f32, FIELDS>(
        subgroupAdd(values[0]), subgroupAdd(values[1]), subgroupAdd(values[2]),
        subgroupAdd(values[3]), subgroupAdd(values[4]), subgroupAdd(values[5]),
        subgroupAdd(values[6]), subgroupAdd(values[7]), subgroupAdd(values[8]),
    );
    if reader {
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
