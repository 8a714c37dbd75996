// Deformation to the view's time, one invocation per Gaussian: what systems/deform.rs
// computes into the Deformed component (μ(t), q(t), s(t), σ(t) and the SH colour seen from
// the camera centre).

@group(0) @binding(3) var<storage, read_write> deformed: array<f32>;

@compute @workgroup_size(64)
fn deform(@builtin(global_invocation_id) gid: vec3<u32>,
          @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gaussian_index(gid, groups);
    if i >= frame.count {
        return;
    }
    let g = load_gaussian(i);
    let dtw = warped_dtw(i);
    let mean = g.mean + fourier_offset(g, dtw);
    let rotation = rotation_at(g.c0, g.c1, dtw);
    let scale = scale_at(g.d0, scale_velocity(g.d1), dtw);
    let opacity = sigmoid(g.logit) * temporal_factor(g.temporal_scale, dtw).factor;
    let count = sh_count(frame.sh_degree);
    let n = sh_unit(mean - frame.eye.xyz).xyz;
    let color = max(sh_raw_rgb(count, g.sh, sh_basis(count, n)), vec3<f32>(0.0));

    let at = i * DEFORMED_STRIDE;
    deformed[at] = mean.x;
    deformed[at + 1u] = mean.y;
    deformed[at + 2u] = mean.z;
    deformed[at + 3u] = rotation.x;
    deformed[at + 4u] = rotation.y;
    deformed[at + 5u] = rotation.z;
    deformed[at + 6u] = rotation.w;
    deformed[at + 7u] = scale.x;
    deformed[at + 8u] = scale.y;
    deformed[at + 9u] = scale.z;
    deformed[at + 10u] = opacity;
    deformed[at + 11u] = color.x;
    deformed[at + 12u] = color.y;
    deformed[at + 13u] = color.z;
}
