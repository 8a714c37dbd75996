//! Per-Gaussian components: plain `#[repr(C)]` data, one Gaussian = one entity.
//!
//! Optimised fields live in [`Param`] components; each has a [`Grad`] (this iteration's gradient)
//! and an [`Adam`] (first and second moments) of the same shape, so the optimiser, the cloner and
//! the pruner treat every field alike.

use bevy_ecs::component::{Component, Mutable};
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::model::deform::FOURIER_TERMS;
use crate::model::sh::SH_COEFFS;

/// Canonical mean μ.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Position {
    pub mean: [f32; 3],
}

/// Fourier motion coefficients M^c, M^s (K × 3) and phases (paper: only `phase[0]` is used).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Fourier {
    pub cos: [[f32; 3]; FOURIER_TERMS],
    pub sin: [[f32; 3]; FOURIER_TERMS],
    pub phase: [f32; FOURIER_TERMS],
}

/// Temporal centre t_i (fixed at initialisation) and raw temporal scale.
///
/// `scale[0]` is log ψ for the RBF opacity; the asymmetric form uses `scale` as the raw
/// left/right widths.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Temporal {
    pub center: f32,
    pub scale: [f32; 2],
}

/// Spatial opacity σ^s as a logit.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Opacity {
    pub logit: f32,
}

/// Quaternion polynomial q(t) = normalise(c0 + c1·Δt'), quaternions as [w, x, y, z].
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Rotation {
    pub c0: [f32; 4],
    pub c1: [f32; 4],
}

/// Log-scale polynomial s(t) = exp(d0 + d1·Δt').
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Scale {
    pub d0: [f32; 3],
    pub d1: [f32; 3],
}

/// Spherical-harmonic colour coefficients up to degree 3 (band 0 is the DC term).
#[derive(Component, Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Color {
    pub sh: [[f32; 3]; SH_COEFFS],
}

impl Default for Color {
    fn default() -> Self {
        Self::zeroed()
    }
}

/// Densification statistics accumulated since the last densification step.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct GradAccum {
    /// Σ w(t)·g(t): w = σ(t) with VAD, 1 without; g = ‖∂L/∂μ2D‖ in NDC units.
    pub weighted_grad: f32,
    /// Σ w(t).
    pub weight: f32,
    /// Σ ψ̄(t): normalised lifespan in each counted view (for TAT).
    pub lifespan_sum: f32,
    /// Number of counted views.
    pub count: u32,
    /// Largest screen radius (pixels) seen.
    pub max_radius: f32,
}

/// The warped temporal offset Δt' = W(t − t_i) at the current time.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct WarpedTime {
    pub dt: f32,
    pub dtw: f32,
}

/// The Gaussian deformed to the current time: what the splatting stage draws.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Deformed {
    pub mean: [f32; 3],
    pub rotation: [f32; 4],
    pub scale: [f32; 3],
    /// σ(t), including the spatial opacity.
    pub opacity: f32,
    pub color: [f32; 3],
}

impl Deformed {
    pub fn mean(&self) -> Vec3 {
        Vec3::from_array(self.mean)
    }
}

/// Index of this Gaussian in the splatting stage's arrays for the current iteration.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SplatSlot(pub u32);

/// An optimised parameter component: all-`f32` plain data.
pub trait Param: Component<Mutability = Mutable> + Pod + Default + Send + Sync + 'static {
    /// Human-readable group name (for logs and NaN reports).
    const NAME: &'static str;

    fn values(&self) -> &[f32] {
        bytemuck::cast_slice(std::slice::from_ref(self))
    }

    fn values_mut(&mut self) -> &mut [f32] {
        bytemuck::cast_slice_mut(std::slice::from_mut(self))
    }
}

/// Implements [`Param`] for each `component => "name"` pair.
macro_rules! params {
    ($($component:ty => $name:literal),* $(,)?) => {
        $(impl Param for $component {
            const NAME: &'static str = $name;
        })*
    };
}

params!(
    Position => "position",
    Fourier => "fourier",
    Temporal => "temporal",
    Opacity => "opacity",
    Rotation => "rotation",
    Scale => "scale",
    Color => "color",
);

/// This iteration's gradient of the loss with respect to parameter component `P`.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Grad<P: Param>(pub P);

/// Adam first and second moments for parameter component `P`.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Adam<P: Param> {
    pub m: P,
    pub v: P,
}

/// Every parameter of a new Gaussian, with zeroed gradients, Adam moments and statistics.
///
/// This is the one place that lists the components of a Gaussian.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GaussianParams {
    pub position: Position,
    pub fourier: Fourier,
    pub temporal: Temporal,
    pub opacity: Opacity,
    pub rotation: Rotation,
    pub scale: Scale,
    pub color: Color,
}

/// The parameter components of one Gaussian, as a read-only query.
pub type ParamRefs<'a> = (
    &'a Position,
    &'a Fourier,
    &'a Temporal,
    &'a Opacity,
    &'a Rotation,
    &'a Scale,
    &'a Color,
);

impl GaussianParams {
    /// Copies the components of a [`ParamRefs`] query item.
    pub fn from_refs(refs: ParamRefs<'_>) -> Self {
        let (position, fourier, temporal, opacity, rotation, scale, color) = refs;
        Self {
            position: *position,
            fourier: *fourier,
            temporal: *temporal,
            opacity: *opacity,
            rotation: *rotation,
            scale: *scale,
            color: *color,
        }
    }

    /// The full component bundle for spawning this Gaussian.
    pub fn bundle(self) -> GaussianBundle {
        (
            (
                self.position,
                self.fourier,
                self.temporal,
                self.opacity,
                self.rotation,
                self.scale,
                self.color,
            ),
            fresh_optimizer_state(),
            (
                GradAccum::default(),
                WarpedTime::default(),
                Deformed::default(),
                SplatSlot::default(),
            ),
        )
    }
}

/// Every component of one Gaussian.
pub type GaussianBundle = (
    (Position, Fourier, Temporal, Opacity, Rotation, Scale, Color),
    OptimizerState,
    (GradAccum, WarpedTime, Deformed, SplatSlot),
);

/// Adam moments of every parameter group.
pub type AdamMoments = (
    Adam<Position>,
    Adam<Fourier>,
    Adam<Temporal>,
    Adam<Opacity>,
    Adam<Rotation>,
    Adam<Scale>,
    Adam<Color>,
);

/// Gradients and Adam moments of every parameter group.
pub type OptimizerState = (
    (
        Grad<Position>,
        Grad<Fourier>,
        Grad<Temporal>,
        Grad<Opacity>,
        Grad<Rotation>,
        Grad<Scale>,
        Grad<Color>,
    ),
    AdamMoments,
);

/// Zeroed gradients and Adam moments for every parameter group (for new Gaussians).
pub fn fresh_optimizer_state() -> OptimizerState {
    (
        (
            Grad::<Position>::default(),
            Grad::<Fourier>::default(),
            Grad::<Temporal>::default(),
            Grad::<Opacity>::default(),
            Grad::<Rotation>::default(),
            Grad::<Scale>::default(),
            Grad::<Color>::default(),
        ),
        (
            Adam::<Position>::default(),
            Adam::<Fourier>::default(),
            Adam::<Temporal>::default(),
            Adam::<Opacity>::default(),
            Adam::<Rotation>::default(),
            Adam::<Scale>::default(),
            Adam::<Color>::default(),
        ),
    )
}
