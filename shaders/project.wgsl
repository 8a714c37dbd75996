// EWA projection of each deformed Gaussian, one invocation per Gaussian: what
// systems/splat.rs::project_splat computes with src/model/project.rs::project_beyond,
// including its culling (σ(t) < 1/255, nearer than the near plane, det cov2d ≤ 0, screen box
// outside the image), after which the splat is all zeros. Under FLAG_MARK_FADED a culled splat
// that src/model/project.rs::in_frustum keeps (too faint, or its opacity-sized box off the
// image while its 3σ box is not) is marked `faded`.

@group(0) @binding(1) var<storage, read> deformed: array<f32>;
@group(0) @binding(2) var<storage, read_write> splats: array<f32>;

struct Projected {
    visible: bool,
    mean2d: vec2<f32>,
    extent: vec2<f32>,
    conic: vec3<f32>,
    depth: f32,
}

fn project_beyond(mean: vec3<f32>, quat: vec4<f32>, scale: vec3<f32>, opacity: f32) -> Projected {
    var none: Projected;
    if !(opacity >= frame.cull.y) {
        return none;
    }
    let e = ewa(mean, quat, scale);
    if !(e.p.z >= frame.cull.x) {
        return none;
    }
    let det = det_2x2(e.cov2d);
    if !(det > 0.0) {
        return none;
    }
    let conic = inverse_2x2(e.cov2d, det);
    // opacity·exp(−½ r²) ≥ 1/255 ⇔ r ≤ sqrt(2 ln(255·opacity)) standard deviations.
    let radius = sqrt(max(2.0 * log(255.0 * opacity), 0.0));
    let extent = vec2<f32>(radius * sqrt(e.cov2d.x), radius * sqrt(e.cov2d.z));
    let lo = e.mean2d - extent;
    let hi = e.mean2d + extent;
    if hi.x <= 0.0 || hi.y <= 0.0 || lo.x >= frame.view.x || lo.y >= frame.view.y {
        return none;
    }
    return Projected(true, e.mean2d, extent, conic, e.p.z);
}

// src/model/project.rs::in_frustum: in front of the near plane, det cov2d > 0 and a 3σ screen
// box overlapping the image, whatever the opacity.
fn in_frustum(mean: vec3<f32>, quat: vec4<f32>, scale: vec3<f32>) -> bool {
    let e = ewa(mean, quat, scale);
    if !(e.p.z >= frame.cull.x) || !(det_2x2(e.cov2d) > 0.0) {
        return false;
    }
    let extent = 3.0 * vec2<f32>(sqrt(e.cov2d.x), sqrt(e.cov2d.z));
    let lo = e.mean2d - extent;
    let hi = e.mean2d + extent;
    return hi.x > 0.0 && hi.y > 0.0 && lo.x < frame.view.x && lo.y < frame.view.y;
}

@compute @workgroup_size(64)
fn project(@builtin(global_invocation_id) gid: vec3<u32>,
           @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gaussian_index(gid, groups);
    if i >= frame.count {
        return;
    }
    let d = i * DEFORMED_STRIDE;
    let mean = vec3<f32>(deformed[d], deformed[d + 1u], deformed[d + 2u]);
    let quat = vec4<f32>(deformed[d + 3u], deformed[d + 4u], deformed[d + 5u], deformed[d + 6u]);
    let scale = vec3<f32>(deformed[d + 7u], deformed[d + 8u], deformed[d + 9u]);
    let opacity = deformed[d + 10u];
    let color = vec3<f32>(deformed[d + 11u], deformed[d + 12u], deformed[d + 13u]);
    let p = project_beyond(mean, quat, scale, opacity);

    let at = i * SPLAT_STRIDE;
    var record: array<f32, 16>;
    if p.visible {
        record = array<f32, 16>(
            p.mean2d.x, p.mean2d.y, p.extent.x, p.extent.y,
            p.conic.x, p.conic.y, p.conic.z, p.depth,
            color.x, color.y, color.z, opacity,
            1.0, 0.0, 0.0, 0.0,
        );
    } else if (frame.flags & FLAG_MARK_FADED) != 0u && in_frustum(mean, quat, scale) {
        record[13] = 1.0;
    }
    for (var k = 0u; k < SPLAT_STRIDE; k++) {
        splats[at + k] = record[k];
    }
}
