
// Portable sums (no float atomics): the workgroup adds the shares of its pixels in workgroup
// memory, and each (tile, splat) entry gets one partial gradient; raster_reduce.wgsl then sums
// each splat's entries. Deterministic.

// Per sorted entry: the gradient fields.
@group(0) @binding(7) var<storage, read_write> entry_grads: array<f32>;

var<workgroup> shares: array<f32, 2304>; // FIELDS × TILE_PIXELS

// Called by every invocation of the workgroup (it holds barriers).
fn add_shares(li: u32, entry: u32, values: array<f32, FIELDS>) {
    var share = values; // a variable, so it can be indexed dynamically
    for (var field = 0u; field < FIELDS; field++) {
        shares[field * TILE_PIXELS + li] = share[field];
    }
    for (var stride = TILE_PIXELS / 2u; stride > 0u; stride /= 2u) {
        workgroupBarrier();
        if li < stride {
            for (var field = 0u; field < FIELDS; field++) {
                let a = field * TILE_PIXELS + li;
                shares[a] += shares[a + stride];
            }
        }
    }
    workgroupBarrier();
    if li < FIELDS {
        entry_grads[FIELDS * entry + li] = shares[li * TILE_PIXELS];
    }
    // The next entry overwrites the shares only after every reader is done.
    workgroupBarrier();
}
