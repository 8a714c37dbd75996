//! Gradients from the image back to every parameter component.

use bevy_ecs::prelude::*;
use glam::Vec3;
use rayon::prelude::*;

use crate::components::{
    Color, ColorRest, Deformed, Fourier, Grad, MotionWeights, Opacity, Position, Rotation, Scale,
    SplatSlot, Temporal, TimeWindow, WarpedTime, sh_coefficients, split_sh,
};
use crate::gpu::GpuRasterizer;
use crate::model::deform::{
    MotionBasis, TemporalOpacity, centre_gradient, fourier_offset_backward,
    polynomial_dtw_backward, rotation_at_backward, scale_at_backward, scale_velocity,
    temporal_opacity_backward, temporal_opacity_dtw_backward, window_factor,
};
use crate::model::project::NEAR_PLANE;
#[cfg(doc)]
use crate::model::project::project_backward;
use crate::model::project_lanes::{
    GaussianLanes, LANES, ProjectGradLanes, ViewTerms, project_backward_lanes,
};
use crate::model::sh::sh_to_rgb_backward;
use crate::model::shared_motion::{MAX_MOTION_BASES, accumulate_bases_gradient, weights_gradient};
use crate::model::warp::TimeWarp;
use crate::raster::{Splat, SplatGrad};
use crate::resources::{
    DeformedGrad, LossImage, Settings, SharedMotion, SplatBuffers, TrainState, ViewSample,
};
use crate::systems::deform::DeformInputs;
use crate::systems::densify::ndc_gradient_norm;
use crate::systems::prefetch::{RowsAhead, prefetch};
use crate::systems::splat::gather_lanes;

/// Back-propagates the image gradient through blending and projection to each slot's deformed
/// Gaussian, and records the NDC-space 2D mean gradient norm used by densification. Blending
/// is differentiated on the GPU when there is a [`GpuRasterizer`] resource.
pub fn backward_splats(
    sample: Res<ViewSample>,
    loss: Res<LossImage>,
    mut buffers: ResMut<SplatBuffers>,
    gpu: Option<ResMut<GpuRasterizer>>,
    gaussians: Query<(&Deformed, &SplatSlot)>,
) -> Result {
    let buffers = &mut *buffers;
    let camera = sample.camera;
    let width = camera.width as usize;
    match gpu {
        Some(mut gpu) => gpu.backward(&buffers.splats, &loss.d_color, &mut buffers.splat_grads)?,
        None => buffers.rasterizer.backward(
            &buffers.splats,
            &loss.d_color,
            width,
            &mut buffers.splat_grads,
        ),
    }

    // One pass over the slots: the densification statistics' gradient sample, while the splat
    // gradients are at hand, and the chain rule through the projection.
    let half = glam::Vec2::new(0.5 * camera.width as f32, 0.5 * camera.height as f32);
    let terms = ViewTerms::new(&camera, NEAR_PLANE);
    let SplatBuffers {
        splats,
        splat_grads,
        deformed_grads,
        gradient_reached,
        ndc_grad_norm,
        ..
    } = buffers;
    let slots = splats.len();
    ndc_grad_norm.resize(slots, 0.0);
    deformed_grads.resize(slots, DeformedGrad::default());
    gradient_reached.resize(slots, false);
    // The deformed Gaussians are read from their components, table by table: the splatting
    // stage numbered the slots of each table's rows consecutively from its first.
    let tables = gaussians
        .contiguous_iter()
        .expect("Gaussian components are stored in tables, so the query is dense");
    for (deformed, table_slots) in tables {
        let Some(first) = table_slots.first() else {
            continue;
        };
        let range = first.0 as usize..first.0 as usize + deformed.len();
        if range.end > slots {
            return Err(format!(
                "the splatting stage drew {slots} Gaussians but the population has more: the \
                 splat system must run after the last change to the population and before \
                 backward_splats"
            )
            .into());
        }
        /// Slots per parallel task (a multiple of [`LANES`]).
        const CHUNK: usize = 256 * LANES;
        deformed
            .par_chunks(CHUNK)
            .zip(splats[range.clone()].par_chunks(CHUNK))
            .zip(splat_grads[range.clone()].par_chunks(CHUNK))
            .zip(ndc_grad_norm[range.clone()].par_chunks_mut(CHUNK))
            .zip(deformed_grads[range.clone()].par_chunks_mut(CHUNK))
            .zip(gradient_reached[range].par_chunks_mut(CHUNK))
            .for_each(|(((((d, s), g), ndc_norm), grad), reached)| {
                chain_projection(d, s, g, &terms, half, ndc_norm, grad, reached)
            });
    }
    Ok(())
}

crate::raster::simd_kernel! {
    /// For a chunk of slots: the densification statistics' gradient sample, and each drawn
    /// splat's gradient chained through the projection, eight Gaussians per vector
    /// ([`project_backward_lanes`], the same values as [`project_backward`] one at a time);
    /// splats that were not drawn or got no gradient get none and are not `reached`.
    fn chain_projection(
        deformed: &[Deformed],
        splats: &[Splat],
        grads: &[SplatGrad],
        terms: &ViewTerms,
        half: glam::Vec2,
        ndc_norm: &mut [f32],
        out: &mut [DeformedGrad],
        reached: &mut [bool],
    ) {
        let mut lanes = GaussianLanes::default();
        let mut d_mean2d = [[0f32; LANES]; 2];
        let mut d_conic = [[0f32; LANES]; 3];
        let mut chained = ProjectGradLanes::default();
        for (k, group) in deformed.chunks(LANES).enumerate() {
            let range = k * LANES..k * LANES + group.len();
            let (splats, grads) = (&splats[range.clone()], &grads[range.clone()]);
            let any_drawn = gather_gradient_lanes(splats, grads, &mut d_mean2d, &mut d_conic);
            if any_drawn {
                if group.len() < LANES {
                    lanes = GaussianLanes::default();
                }
                gather_lanes(group, &mut lanes);
                project_backward_lanes(&lanes, &d_mean2d, &d_conic, terms, &mut chained);
            }
            scatter_chained(
                &chained,
                splats,
                grads,
                half,
                &mut ndc_norm[range.clone()],
                &mut out[range.clone()],
                &mut reached[range],
            );
        }
    }
}

/// Whether a slot's splat was drawn and got a gradient: only then is there something to
/// chain back (splats behind opaque pixels get none).
#[inline(always)]
fn chains(splat: &Splat, grad: &SplatGrad) -> bool {
    splat.visible && *grad != SplatGrad::default()
}

/// Copies the 2D-mean and conic gradients of up to [`LANES`] slots into lanes (out of line,
/// as [`gather_lanes`]); whether any of them [`chains`].
#[inline(never)]
fn gather_gradient_lanes(
    splats: &[Splat],
    grads: &[SplatGrad],
    d_mean2d: &mut [[f32; LANES]; 2],
    d_conic: &mut [[f32; LANES]; 3],
) -> bool {
    let mut any = false;
    for (i, (s, g)) in splats.iter().zip(grads).enumerate() {
        d_mean2d[0][i] = g.mean2d.x;
        d_mean2d[1][i] = g.mean2d.y;
        for (lanes, &value) in d_conic.iter_mut().zip(&g.conic) {
            lanes[i] = value;
        }
        any |= chains(s, g);
    }
    any
}

/// Writes the chained gradients of up to [`LANES`] slots (out of line, as [`gather_lanes`]).
#[inline(never)]
fn scatter_chained(
    chained: &ProjectGradLanes,
    splats: &[Splat],
    grads: &[SplatGrad],
    half: glam::Vec2,
    ndc_norm: &mut [f32],
    out: &mut [DeformedGrad],
    reached: &mut [bool],
) {
    let slots = splats.iter().zip(grads).zip(ndc_norm).zip(out).zip(reached);
    for (i, ((((s, g), ndc_norm), grad), reached)) in slots.enumerate() {
        *ndc_norm = ndc_gradient_norm(s, g, half);
        if !chains(s, g) {
            (*grad, *reached) = (DeformedGrad::default(), false);
            continue;
        }
        let lane = |v: &[[f32; LANES]; 3]| Vec3::new(v[0][i], v[1][i], v[2][i]);
        *grad = DeformedGrad {
            mean: lane(&chained.mean),
            rotation: chained.quat.map(|q| q[i]),
            scale: lane(&chained.scale),
            opacity: g.opacity,
            color: g.color,
        };
        *reached = *grad != DeformedGrad::default();
    }
}

/// The gradient components written by the backward pass.
pub type ParamGrads<'a> = crate::components::GradMuts<'a>;

/// Chains each deformed Gaussian's gradient through the deformation model to its parameters
/// ([`ChainRule::rows`]), into its `Grad` components.
pub fn backward_parameters(
    settings: Res<Settings>,
    state: Res<TrainState>,
    sample: Res<ViewSample>,
    buffers: Res<SplatBuffers>,
    mut gaussians: Query<(DeformInputs, &Deformed, &SplatSlot, ParamGrads)>,
) {
    let chain = ChainRule::for_view(&settings, &state, &sample);
    let deformed_grads = &buffers.deformed_grads;
    gaussians
        .contiguous_par_iter_mut()
        .expect("Gaussian components are stored in tables, so the query is dense")
        .for_each(|(inputs, deformed, slots, grads)| {
            let (params, warped, windows) = inputs;
            let (
                mut g_pos,
                mut g_fourier,
                mut g_temporal,
                mut g_opacity,
                mut g_rotation,
                mut g_scale,
                mut g_color,
                mut g_rest,
            ) = grads;
            let mut out = RowGrads {
                position: &mut g_pos[..],
                fourier: &mut g_fourier[..],
                temporal: &mut g_temporal[..],
                opacity: &mut g_opacity[..],
                rotation: &mut g_rotation[..],
                scale: &mut g_scale[..],
                color: &mut g_color[..],
                rest: g_rest.as_mut().map(|g| &mut g[..]),
            };
            let rows = ChainRows {
                params,
                warped,
                windows,
                deformed,
                slots,
            };
            chain.rows(rows, deformed_grads, &mut out);
        });
}

/// The inputs of the chain rule for consecutive Gaussians of one table.
#[derive(Clone, Copy)]
pub(crate) struct ChainRows<'a> {
    pub params: ParamColumns<'a>,
    pub warped: &'a [WarpedTime],
    pub windows: Option<&'a [TimeWindow]>,
    pub deformed: &'a [Deformed],
    pub slots: &'a [SplatSlot],
}

/// The gradient columns of one table chunk, as [`backward_parameters`] writes them (or a
/// block's gradients, which the fused pass keeps on the stack).
pub(crate) struct RowGrads<'a> {
    pub position: &'a mut [Grad<Position>],
    pub fourier: &'a mut [Grad<Fourier>],
    pub temporal: &'a mut [Grad<Temporal>],
    pub opacity: &'a mut [Grad<Opacity>],
    pub rotation: &'a mut [Grad<Rotation>],
    pub scale: &'a mut [Grad<Scale>],
    pub color: &'a mut [Grad<Color>],
    pub rest: Option<&'a mut [Grad<ColorRest>]>,
}

impl RowGrads<'_> {
    /// No gradient reached row `i`'s parameters.
    fn zero(&mut self, i: usize) {
        self.position[i] = Grad::default();
        self.fourier[i] = Grad::default();
        self.temporal[i] = Grad::default();
        self.opacity[i] = Grad::default();
        self.rotation[i] = Grad::default();
        self.scale[i] = Grad::default();
        self.color[i] = Grad::default();
        if let Some(rest) = self.rest.as_deref_mut() {
            rest[i] = Grad::default();
        }
    }

    fn prefetch(&self, i: usize) {
        prefetch(&self.position[i..=i]);
        prefetch(&self.fourier[i..=i]);
        prefetch(&self.temporal[i..=i]);
        prefetch(&self.opacity[i..=i]);
        prefetch(&self.rotation[i..=i]);
        prefetch(&self.scale[i..=i]);
        prefetch(&self.color[i..=i]);
        if let Some(rest) = self.rest.as_deref() {
            prefetch(&rest[i..=i]);
        }
    }
}

/// What the chain rule of [`backward_parameters`] needs besides each Gaussian's own data.
pub(crate) struct ChainRule {
    motion: MotionBasis,
    opacity_model: TemporalOpacity,
    scale_motion: bool,
    learn_centres: bool,
    warp: TimeWarp,
    sh_degree: u32,
    eye: Vec3,
    time: f32,
}

/// One table chunk's parameter columns, as the contiguous query gives them.
pub(crate) type ParamColumns<'a> = (
    &'a [Position],
    &'a [Fourier],
    &'a [Temporal],
    &'a [Opacity],
    &'a [Rotation],
    &'a [Scale],
    &'a [Color],
    Option<&'a [ColorRest]>,
);

/// Requests row `i` of every parameter column.
fn prefetch_parameters(params: ParamColumns, i: usize) {
    let (position, fourier, temporal, opacity, rotation, scale, color, rest) = params;
    prefetch(&position[i..=i]);
    prefetch(&fourier[i..=i]);
    prefetch(&temporal[i..=i]);
    prefetch(&opacity[i..=i]);
    prefetch(&rotation[i..=i]);
    prefetch(&scale[i..=i]);
    prefetch(&color[i..=i]);
    if let Some(rest) = rest {
        prefetch(&rest[i..=i]);
    }
}

impl ChainRule {
    /// The chain rule for the view being trained on.
    pub(crate) fn for_view(settings: &Settings, state: &TrainState, sample: &ViewSample) -> Self {
        Self {
            motion: settings.motion_basis(),
            opacity_model: settings.opacity,
            scale_motion: settings.model.scale_motion,
            learn_centres: settings.train.lr.temporal_center > 0.0,
            warp: settings.warp,
            sh_degree: state.sh_degree,
            eye: sample.camera.center(),
            time: sample.time,
        }
    }

    /// Chains the gradient of each row's deformed Gaussian (`deformed_grads`, by slot) into
    /// that row of `out`; rows that got none get zero gradients.
    ///
    /// Most Gaussians of a real capture get no gradient from a view (not drawn, or only
    /// behind opaque pixels): their gradients are zeroed in one pass, and the few that get
    /// one, scattered over the table, are worked on a few rows behind the scan, which
    /// prefetches their rows ([`RowsAhead`]).
    pub(crate) fn rows(
        &self,
        rows: ChainRows,
        deformed_grads: &[DeformedGrad],
        out: &mut RowGrads,
    ) {
        let ChainRows {
            params,
            warped,
            windows,
            deformed,
            slots,
        } = rows;
        let mut ahead = RowsAhead::<DeformedGrad>::default();
        for (i, slot) in slots.iter().enumerate() {
            let d = deformed_grads[slot.0 as usize];
            if d == DeformedGrad::default() {
                out.zero(i);
                continue;
            }
            prefetch_parameters(params, i);
            prefetch(&deformed[i..=i]);
            prefetch(&warped[i..=i]);
            out.prefetch(i);
            if let Some((row, d)) = ahead.push(i, d) {
                self.row(params, warped, windows, deformed, row, d, out);
            }
        }
        while let Some((row, d)) = ahead.pop() {
            self.row(params, warped, windows, deformed, row, d, out);
        }
    }

    /// Chains deformed-Gaussian gradient `d` of row `i` through the deformation model into
    /// that row of `out`.
    #[allow(clippy::too_many_arguments)]
    fn row(
        &self,
        params: ParamColumns,
        warped: &[WarpedTime],
        windows: Option<&[TimeWindow]>,
        deformed: &[Deformed],
        i: usize,
        d: DeformedGrad,
        out: &mut RowGrads,
    ) {
        let (_, fourier, temporal, opacity, rotation, scale, color, rest) = params;
        let (fourier, temporal, opacity) = (&fourier[i], &temporal[i], &opacity[i]);
        let (rotation, scale) = (&rotation[i], &scale[i]);
        let (warped, window) = (&warped[i], windows.map(|w| &w[i]));
        let dtw = warped.dtw;
        // A time window scales σ(t) by a factor of time alone: dL/dσ scales alike.
        let d_sigma = d.opacity * window.map_or(1.0, |w| window_factor(w, self.time));

        let (d_sh, d_dir) = sh_to_rgb_backward(
            self.sh_degree,
            &sh_coefficients(&color[i], rest.map(|r| &r[i])),
            deformed[i].mean() - self.eye,
            d.color,
        );
        let d_mean = d.mean + d_dir;
        let f = fourier_offset_backward(
            &fourier.cos,
            &fourier.sin,
            &fourier.phase,
            self.motion,
            dtw,
            d_mean,
        );
        let (d_c0, d_c1) = rotation_at_backward(rotation.c0, rotation.c1, dtw, d.rotation);
        let scale_velocity = scale_velocity(scale.d1, self.scale_motion);
        let (d_d0, mut d_d1) = scale_at_backward(scale.d0, scale_velocity, dtw, d.scale);
        if !self.scale_motion {
            d_d1 = [0.0; 3];
        }
        let model = self.opacity_model;
        let (d_logit, d_raw) =
            temporal_opacity_backward(model, opacity.logit, temporal.scale, dtw, d_sigma);

        out.position[i].0 = Position {
            mean: d_mean.to_array(),
        };
        out.fourier[i].0 = Fourier {
            cos: f.cos,
            sin: f.sin,
            phase: f.phase,
        };
        // The centre's gradient only where it is learnt: as a constant it has none.
        let center = if self.learn_centres {
            let d_dtw = f.dtw
                + polynomial_dtw_backward(d_c0, rotation.c1, d_d0, scale_velocity)
                + temporal_opacity_dtw_backward(model, opacity.logit, temporal.scale, dtw, d_sigma);
            centre_gradient(d_dtw, &self.warp, temporal.center, warped.dt)
        } else {
            0.0
        };
        out.temporal[i].0 = Temporal {
            center,
            scale: d_raw,
        };
        out.opacity[i].0 = Opacity { logit: d_logit };
        out.rotation[i].0 = Rotation { c0: d_c0, c1: d_c1 };
        out.scale[i].0 = Scale { d0: d_d0, d1: d_d1 };
        let (d_dc, d_rest) = split_sh(&d_sh);
        out.color[i].0 = d_dc;
        if let Some(rest) = out.rest.as_deref_mut() {
            rest[i].0 = d_rest;
        }
    }
}

/// Rows of a table that [`backward_shared_motion`] sums in one task. The chunks are fixed and
/// their sums added in order, so dL/dU is the same whatever the number of threads.
pub const SHARED_MOTION_CHUNK: usize = 4096;

/// The gradients of the shared motion (`model.shared_motion`, see
/// [`crate::model::shared_motion`]): dL/dw_ib = g_i·u_b(t) into each Gaussian's
/// `Grad<MotionWeights>`, and dL/dU = Σ_i w_ib·g_i spread over the two knots around the view's
/// time into [`SharedMotion::grad`].
///
/// g_i = dL/d(mean_i(t)) is the position gradient [`backward_parameters`] has written: the
/// shared motion adds to the mean as the canonical position does, so dL/dμ_i = g_i.
pub fn backward_shared_motion(
    sample: Res<ViewSample>,
    mut shared: ResMut<SharedMotion>,
    mut gaussians: Query<(&MotionWeights, &Grad<Position>, &mut Grad<MotionWeights>)>,
) {
    let shared = &mut *shared;
    let at = shared.bases.evaluate(sample.time);
    type Sums = [[f64; 3]; MAX_MOTION_BASES];
    let mut sums: Sums = Default::default();
    let tables = gaussians
        .contiguous_iter_mut()
        .expect("Gaussian components are stored in tables, so the query is dense");
    for (weights, d_positions, mut d_weights) in tables {
        let chunks: Vec<Sums> = weights
            .par_chunks(SHARED_MOTION_CHUNK)
            .zip(d_positions.par_chunks(SHARED_MOTION_CHUNK))
            .zip(d_weights[..].par_chunks_mut(SHARED_MOTION_CHUNK))
            .map(|((weights, d_positions), d_weights)| {
                let mut sums: Sums = Default::default();
                for ((w, g), d_w) in weights.iter().zip(d_positions).zip(d_weights) {
                    let g = Vec3::from_array(g.0.mean);
                    if g == Vec3::ZERO {
                        // No gradient reached the Gaussian.
                        *d_w = Grad::default();
                        continue;
                    }
                    d_w.0.w = weights_gradient(&at, g);
                    accumulate_bases_gradient(&w.w, g, &mut sums[..at.count]);
                }
                sums
            })
            .collect();
        for chunk in chunks {
            for (sum, part) in sums.iter_mut().zip(chunk) {
                for (s, p) in sum.iter_mut().zip(part) {
                    *s += p;
                }
            }
        }
    }
    let d_bases: Vec<Vec3> = sums[..at.count]
        .iter()
        .map(|s| glam::DVec3::from_array(*s).as_vec3())
        .collect();
    shared.grad.clear();
    shared.grad.resize(shared.bases.values.len(), [0.0; 3]);
    shared
        .bases
        .evaluate_backward(at.span, &d_bases, &mut shared.grad);
}
