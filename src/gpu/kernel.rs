//! Helpers shared by the compute-kernel wrappers: pipelines, bind groups and one-dimensional
//! dispatches of any size.

use std::sync::atomic::{AtomicU32, Ordering};

/// Most workgroups per dispatch dimension (WebGPU's and Vulkan's guaranteed minimum).
pub(crate) const MAX_GROUPS: u32 = 65_535;

/// The grid width of [`dispatch`]: [`MAX_GROUPS`] unless lowered by
/// [`set_max_dispatch_width`].
static DISPATCH_WIDTH: AtomicU32 = AtomicU32::new(MAX_GROUPS);

/// Caps the workgroups per dispatch dimension of the binning, sort, scan, Adam and statistics
/// kernels, process-wide (clamped into 1..=65535, the default). Dispatches with more
/// workgroups are laid out as 2D grids; lowering the cap runs that layout on small inputs,
/// which is how the tests check it.
pub fn set_max_dispatch_width(width: u32) {
    DISPATCH_WIDTH.store(width.clamp(1, MAX_GROUPS), Ordering::Relaxed);
}
/// Invocations per workgroup of the one-dimensional kernels.
pub(crate) const GROUP_SIZE: u32 = 256;

/// One compute pipeline per entry point of `source`, compiled once, with layouts derived from
/// the shader (each entry point's layout has only the bindings it uses).
pub(crate) fn pipelines<const N: usize>(
    device: &wgpu::Device,
    label: &str,
    source: &str,
    entries: [&str; N],
) -> [wgpu::ComputePipeline; N] {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    entries.map(|entry| {
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module: &module,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        });
        let name = if label == entry {
            entry.to_string()
        } else {
            format!("{label}/{entry}")
        };
        super::profile::register(device, &pipeline, name);
        pipeline
    })
}

/// The first `bytes` of `buffer` as a binding (`arrayLength` in the shader sees them).
pub(crate) fn storage(buffer: &wgpu::Buffer, bytes: u64) -> wgpu::BindingResource<'_> {
    wgpu::BindingResource::Buffer(wgpu::BufferBinding {
        buffer,
        offset: 0,
        size: std::num::NonZeroU64::new(bytes),
    })
}

/// A bind group for group 0 of `pipeline` from (binding, resource) pairs.
pub(crate) fn bind(
    device: &wgpu::Device,
    pipeline: &wgpu::ComputePipeline,
    entries: Vec<(u32, wgpu::BindingResource<'_>)>,
) -> wgpu::BindGroup {
    let entries: Vec<wgpu::BindGroupEntry> = entries
        .into_iter()
        .map(|(binding, resource)| wgpu::BindGroupEntry { binding, resource })
        .collect();
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    })
}

/// Records `groups` workgroups of `pipeline`, laid out as a 2D grid when they exceed
/// [`MAX_GROUPS`] (or the width set by [`set_max_dispatch_width`]): the kernels number their workgroup `id.y · num_workgroups.x + id.x` and
/// skip the few past the end. Nothing is recorded for 0 groups.
pub(crate) fn dispatch(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    bind_group: &wgpu::BindGroup,
    groups: u32,
) {
    if groups == 0 {
        return;
    }
    let across = groups.min(DISPATCH_WIDTH.load(Ordering::Relaxed));
    dispatch_grid(
        encoder,
        pipeline,
        bind_group,
        (across, groups.div_ceil(across)),
    );
}

/// Records one compute pass of `pipeline` over a grid of (x, y) workgroups (nothing when
/// either is 0), timed per kernel when [`super::profile`] is on.
pub(crate) fn dispatch_grid(
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::ComputePipeline,
    bind_group: &wgpu::BindGroup,
    (x, y): (u32, u32),
) {
    if x == 0 || y == 0 {
        return;
    }
    let mut pass = super::profile::begin_pass(encoder, pipeline);
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bind_group, &[]);
    pass.dispatch_workgroups(x, y, 1);
}

/// Workgroups of [`GROUP_SIZE`] invocations that cover `threads` invocations.
pub(crate) fn groups_for(threads: u32) -> u32 {
    threads.div_ceil(GROUP_SIZE)
}
