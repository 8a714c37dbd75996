
// How the blending kernels visit and read a batch where the adapter offers subgroup operations:
// a subgroup's invocations visit the same slots (the union of their segments' masks, so control
// stays uniform over the subgroup) and one of them reads each staged splat for all. Lavapipe
// reads workgroup memory one invocation at a time (8 per SIMD vector), so one read and a
// broadcast cost far less than every invocation reading; on a hardware GPU a broadcast read
// and a subgroup broadcast cost about the same.

fn lane_candidates(own: u32) -> u32 {
    return subgroupOr(own);
}

fn any_open(open: bool) -> bool {
    return subgroupAny(open);
}

// Whether invocation `li` is its subgroup's first active one (what subgroupElect would say).
fn first_active(li: u32) -> bool {
    return subgroupBroadcastFirst(li) == li;
}

fn staged_box(j: u32, li: u32) -> u32 {
    var box = 0u;
    if first_active(li) {
        box = batch_box[j];
    }
    return subgroupBroadcastFirst(box);
}

// The splat of slot `j` without its extent (the pixel loops use the packed box instead).
fn staged_splat(j: u32, li: u32) -> Splat {
    var s: Splat;
    if first_active(li) {
        s = batch[j];
    }
    return Splat(
        subgroupBroadcastFirst(s.mean),
        vec2<f32>(0.0),
        subgroupBroadcastFirst(s.conic),
        subgroupBroadcastFirst(s.color),
    );
}
