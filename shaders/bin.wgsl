// Tile binning on the GPU, mirroring src/raster/binning.rs entry for entry. With N splats and
// T = tiles_x · tiles_y 16×16 tiles:
//   count_tiles   each splat's tile rectangle, its tile count (scanned into splat_offsets, N + 1
//                 values) and its depth sort key (the f32 bits) with its index as value;
//   (radix sort by depth: stable, so equal depths stay in splat-index order, as on the CPU)
//   depth_counts  the tile counts in depth order (scanned into depth_offsets);
//   emit          one (tile id, entry) pair per covered tile, splat by splat in depth order;
//                 an entry is numbered splat-major like the CPU's (splat_offsets[s] + row-major
//                 index in the rectangle);
//   (stable radix sort by tile id: each tile's entries stay in depth order)
//   finish        sorted_splats[k] (splat of sorted entry k), sorted_position[entry] = k;
//   tile_ranges   tile_offsets[t] = first sorted entry of tile t (t = 0..=T), by binary search.

struct SplatBox {
    mean: vec2<f32>,
    extent: vec2<f32>,
    depth: f32,
    visible: u32,
}

struct BinParams {
    tiles_x: u32,
    tiles_y: u32,
    splat_count: u32,
    tile_count: u32,
}

// 1/16: x · (1/16) rounds exactly like the CPU's x / 16.
const INV_TILE: f32 = 0.0625;

@group(0) @binding(0) var<uniform> params: BinParams;
@group(0) @binding(1) var<storage, read> splats: array<SplatBox>;
@group(0) @binding(2) var<storage, read_write> rects: array<vec4<u32>>;
@group(0) @binding(3) var<storage, read_write> splat_offsets: array<u32>;
@group(0) @binding(4) var<storage, read_write> depth_keys: array<u32>;
@group(0) @binding(5) var<storage, read_write> depth_vals: array<u32>;
@group(0) @binding(6) var<storage, read> order: array<u32>;
@group(0) @binding(7) var<storage, read_write> depth_offsets: array<u32>;
@group(0) @binding(8) var<storage, read_write> tile_keys: array<u32>;
@group(0) @binding(9) var<storage, read_write> entry_ids: array<u32>;
@group(0) @binding(10) var<storage, read_write> entry_splat: array<u32>;
@group(0) @binding(11) var<storage, read> sorted_keys: array<u32>;
@group(0) @binding(12) var<storage, read> sorted_ids: array<u32>;
@group(0) @binding(13) var<storage, read_write> sorted_splats: array<u32>;
@group(0) @binding(14) var<storage, read_write> sorted_position: array<u32>;
@group(0) @binding(15) var<storage, read_write> tile_offsets: array<u32>;

fn thread_index(lid: u32, wid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return (wid.y * groups.x + wid.x) * 256u + lid;
}

// The tiles a splat's screen box overlaps, [x0, y0, x1, y1), as `tile_rect` on the CPU.
fn tile_rect(b: SplatBox) -> vec4<u32> {
    // 2: faded out, counted by the statistics but not drawn.
    if b.visible != 1u {
        return vec4(0u);
    }
    let tiles = vec2(f32(params.tiles_x), f32(params.tiles_y));
    let lo = clamp(floor((b.mean - b.extent) * INV_TILE), vec2(0.0), tiles);
    let hi = clamp(floor((b.mean + b.extent) * INV_TILE) + 1.0, vec2(0.0), tiles);
    if hi.x <= lo.x || hi.y <= lo.y {
        return vec4(0u);
    }
    return vec4(vec2<u32>(lo), vec2<u32>(hi));
}

@compute @workgroup_size(256)
fn count_tiles(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let s = thread_index(lid, wid, groups);
    let n = params.splat_count;
    if s > n {
        return;
    }
    if s == n {
        // The scan turns this into the total.
        splat_offsets[n] = 0u;
        return;
    }
    let b = splats[s];
    let r = tile_rect(b);
    rects[s] = r;
    splat_offsets[s] = (r.z - r.x) * (r.w - r.y);
    depth_keys[s] = bitcast<u32>(b.depth);
    depth_vals[s] = s;
}

@compute @workgroup_size(256)
fn depth_counts(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let i = thread_index(lid, wid, groups);
    let n = params.splat_count;
    if i > n {
        return;
    }
    if i == n {
        depth_offsets[n] = 0u;
        return;
    }
    let s = order[i];
    depth_offsets[i] = splat_offsets[s + 1u] - splat_offsets[s];
}

@compute @workgroup_size(256)
fn emit(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let i = thread_index(lid, wid, groups);
    if i >= params.splat_count {
        return;
    }
    let s = order[i];
    let r = rects[s];
    var dst = depth_offsets[i];
    var entry = splat_offsets[s];
    for (var ty = r.y; ty < r.w; ty++) {
        for (var tx = r.x; tx < r.z; tx++) {
            tile_keys[dst] = ty * params.tiles_x + tx;
            entry_ids[dst] = entry;
            entry_splat[entry] = s;
            dst++;
            entry++;
        }
    }
}

@compute @workgroup_size(256)
fn finish(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let k = thread_index(lid, wid, groups);
    if k >= arrayLength(&sorted_ids) {
        return;
    }
    let entry = sorted_ids[k];
    sorted_position[entry] = k;
    sorted_splats[k] = entry_splat[entry];
}

@compute @workgroup_size(256)
fn tile_ranges(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let t = thread_index(lid, wid, groups);
    if t > params.tile_count {
        return;
    }
    // Lower bound of t in the sorted tile ids.
    var lo = 0u;
    var hi = arrayLength(&sorted_keys);
    while lo < hi {
        let mid = lo + (hi - lo) / 2u;
        if sorted_keys[mid] < t {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    tile_offsets[t] = lo;
}
