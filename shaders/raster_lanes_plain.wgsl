
// How the blending kernels visit and read a batch where the adapter offers no subgroup
// operations: every invocation on its own.

// Called when a blending kernel starts; with subgroups it picks the invocation that reads for
// its subgroup, here every invocation reads for itself.
fn begin_lanes(li: u32) {}

// Of one word of the invocation's segment mask, the slots it visits: its own segment's.
fn lane_candidates(own: u32) -> u32 {
    return own;
}

// Whether any of the invocation's pixels (with subgroups: of its subgroup's) still takes colour.
fn any_open(open: bool) -> bool {
    return open;
}

// Whether the invocation reads the splat (with subgroups: whether its subgroup does).
fn visit_splat(needed: bool) -> bool {
    return needed;
}

// The packed screen box of the splat staged in slot `j`.
fn staged_box(j: u32) -> u32 {
    return batch_box[j];
}

// The splat staged in slot `j`.
fn staged_splat(j: u32) -> Splat {
    return batch[j];
}
