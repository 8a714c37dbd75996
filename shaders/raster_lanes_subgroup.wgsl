
// How the blending kernels visit and read a batch where the adapter offers subgroup operations:
// a subgroup's invocations visit the same slots (the union of their segments' masks, so control
// stays uniform over the subgroup) and one of them reads each staged splat for all. Lavapipe
// reads workgroup memory one invocation at a time (8 per SIMD vector), so one read and a
// broadcast cost far less than every invocation reading; on a hardware GPU a broadcast read
// and a subgroup broadcast cost about the same.

// Whether this invocation reads the splats for its subgroup: the first invocation of the
// subgroup, chosen once when the kernel starts (`begin_lanes`). The blending kernels keep every
// invocation of a subgroup on the same path from there on (the slots they visit and whether
// they read a splat are subgroup-wide), so it stays the first active one; choosing it per read
// cost two more loops over the lanes per visited slot on lavapipe.
var<private> reader: bool;

fn begin_lanes(li: u32) {
    reader = subgroupBroadcastFirst(li) == li;
}

fn lane_candidates(own: u32) -> u32 {
    return subgroupOr(own);
}

fn any_open(open: bool) -> bool {
    return subgroupAny(open);
}

// Whether the subgroup reads the splat: where any of its invocations needs it.
fn visit_splat(needed: bool) -> bool {
    return subgroupAny(needed);
}

fn staged_box(j: u32) -> u32 {
    var box = 0u;
    if reader {
        box = batch_box[j];
    }
    return subgroupBroadcastFirst(box);
}

// The splat of slot `j` without its extent (the pixel loops use the packed box instead).
fn staged_splat(j: u32) -> Splat {
    var s: Splat;
    if reader {
        s = batch[j];
    }
    return Splat(
        subgroupBroadcastFirst(s.mean),
        vec2<f32>(0.0),
        subgroupBroadcastFirst(s.conic),
        subgroupBroadcastFirst(s.color),
    );
}
