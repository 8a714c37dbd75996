
// How the blending kernels visit and read a batch where the adapter offers no subgroup
// operations: every invocation on its own.

// Of one word of the pixel's segment mask, the slots it visits: its own segment's.
fn lane_candidates(own: u32) -> u32 {
    return own;
}

// Whether the pixel (or, with subgroups, any pixel of its subgroup) still takes colour.
fn any_open(open: bool) -> bool {
    return open;
}

// The packed screen box of the splat staged in slot `j`, read for invocation `li`.
fn staged_box(j: u32, li: u32) -> u32 {
    return batch_box[j];
}

// The splat staged in slot `j`, read for invocation `li`.
fn staged_splat(j: u32, li: u32) -> Splat {
    return batch[j];
}
