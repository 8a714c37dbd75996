
// Portable sums (no float atomics): the workgroup adds the shares of its pixels in workgroup
// memory, and each (tile, splat) entry gets one partial gradient; raster_reduce.wgsl then sums
// each splat's entries. Deterministic.

// The entries of word `word` of a batch that the workgroup visits: all those before the last
// contributor of any of its pixels (`useful`) that can be drawn somewhere in the tile, the
// same for every invocation, as the sums below need the whole workgroup at every entry.
fn entry_candidates(own: u32, word: u32, useful: u32) -> u32 {
    return workgroupUniformLoad(&tile_mask[word]) & useful;
}

// The bound on the entries worth visiting: the workgroup's, for the same reason.
fn contributor_bound(contributor: u32, workgroup_bound: u32) -> u32 {
    return workgroup_bound;
}

// Per sorted entry: the gradient fields.
@group(0) @binding(7) var<storage, read_write> entry_grads: array<f32>;

var<workgroup> shares: array<f32, FIELDS * BLEND_INVOCATIONS>;
var<workgroup> row_sums: array<f32, FIELDS * INVOCATION_ROWS>;

// Called by every invocation of the workgroup (it holds barriers), with the sum of its pixels'
// shares. Two barriers per entry: a tree over the invocations would take several, and a
// barrier, not an addition, is what costs. Each of FIELDS · INVOCATION_ROWS invocations first
// adds one field along one row of invocations, then nine add up a field's row sums, always in
// the same order.
fn add_shares(li: u32, entry: u32, values: array<f32, FIELDS>) {
    var share = values; // a variable, so it can be indexed dynamically
    for (var field = 0u; field < FIELDS; field++) {
        shares[field * BLEND_INVOCATIONS + li] = share[field];
    }
    workgroupBarrier();
    if li < FIELDS * INVOCATION_ROWS {
        // Invocation li = field · INVOCATION_ROWS + row sums
        // shares[field · BLEND_INVOCATIONS + row · 16 ..][..16].
        let first = li * TILE;
        var sum = 0.0;
        for (var i = 0u; i < TILE; i++) {
            sum += shares[first + i];
        }
        row_sums[li] = sum;
    }
    // Also orders this entry's reads of `shares` before the next entry's writes; the next
    // entry writes `row_sums` only after its first barrier, which the readers below reach
    // once they are done.
    workgroupBarrier();
    if li < FIELDS {
        var sum = 0.0;
        for (var row = 0u; row < INVOCATION_ROWS; row++) {
            sum += row_sums[li * INVOCATION_ROWS + row];
        }
        entry_grads[FIELDS * entry + li] = sum;
    }
}
