//! Per-Gaussian components: plain `#[repr(C)]` data, one Gaussian = one entity.
//!
//! Optimised fields live in [`Param`] components; each has a [`Grad`] (this iteration's gradient)
//! of the same shape and an [`Adam`] (first and second moments, one bfloat16 per value each),
//! so the optimiser, the cloner and the pruner treat every field alike.

use bevy_ecs::bundle::{Bundle, NoBundleEffect};
use bevy_ecs::component::{Component, Mutable};
use bevy_ecs::world::World;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

use crate::model::adam::{StoredMoments, store_moments_nearest, stored_moments};
use crate::model::deform::FOURIER_TERMS;
use crate::model::sh::SH_COEFFS;
use crate::model::shared_motion::MAX_MOTION_BASES;

/// Canonical mean μ.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Position {
    /// World-space position of the Gaussian at its temporal centre, before motion.
    pub mean: [f32; 3],
}

/// Fourier motion coefficients M^c, M^s (K × 3) and phases (paper: only `phase[0]` is used).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Fourier {
    /// M^c: `cos[f]` is the world-space amplitude of the cos(2π(f + 1)·Δt' + φ) term.
    pub cos: [[f32; 3]; FOURIER_TERMS],
    /// M^s: `sin[f]` is the world-space amplitude of the sin(2π(f + 1)·Δt' + φ) term.
    pub sin: [[f32; 3]; FOURIER_TERMS],
    /// Phases φ in radians: one per frequency, or only `phase[0]` when the phase is shared
    /// (paper form, [`crate::scene::PhaseModel::PerGaussian`]).
    pub phase: [f32; FOURIER_TERMS],
}

/// Temporal centre t_i (fixed at initialisation) and raw temporal scale.
///
/// `scale[0]` is log ψ for the RBF opacity; the asymmetric form uses `scale` as the raw
/// left/right widths.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Temporal {
    /// Temporal centre t_i in normalised time (an anchor frame); fixed unless
    /// `train.lr.temporal_center` > 0 (CPU backend only).
    pub center: f32,
    /// Raw temporal scale: RBF: `[log ψ, unused]`; asymmetric: the left (Δt' < 0) and right
    /// (Δt' ≥ 0) log-widths s, w = min(w_min·exp(s), 1.1).
    pub scale: [f32; 2],
}

/// Spatial opacity σ^s as a logit.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Opacity {
    /// logit(σ^s); the spatial opacity is sigmoid(`logit`).
    pub logit: f32,
}

/// Quaternion polynomial q(t) = normalise(c0 + c1·Δt'), quaternions as [w, x, y, z].
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Rotation {
    /// Constant term c0, an unnormalised quaternion [w, x, y, z].
    pub c0: [f32; 4],
    /// Linear term c1 (per unit of warped normalised time), [w, x, y, z].
    pub c1: [f32; 4],
}

/// Log-scale polynomial s(t) = exp(d0 + d1·Δt').
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Scale {
    /// Constant term d0: natural log of the per-axis standard deviation (world units).
    pub d0: [f32; 3],
    /// Linear term d1 per unit of warped normalised time; ignored unless
    /// `model.scale_motion` is on.
    pub d1: [f32; 3],
}

/// Band-0 (DC) spherical-harmonic coefficient of each channel: the view-independent colour.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Color {
    /// `dc[c]`: the band-0 coefficient of channel c (r, g, b); with [`ColorRest`],
    /// rgb = Σ basis·sh + 0.5, clamped ≥ 0.
    pub dc: [f32; 3],
}

/// Spherical-harmonic coefficients of bands 1–3: the view-dependent colour.
///
/// Only the Gaussians of a model whose `sh_degree` is above 0 carry it (with its [`Grad`] and
/// [`Adam`]); a degree-0 model does not hold 720 bytes per Gaussian of coefficients it never
/// uses. Systems read it as `Option<&ColorRest>`: a Gaussian without it has zero coefficients.
#[derive(Component, Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct ColorRest {
    /// `sh[k - 1][c]`: coefficient k ≥ 1 (band by band in the 3DGS basis order) of channel c.
    pub sh: [[f32; 3]; SH_COEFFS - 1],
}

impl Default for ColorRest {
    fn default() -> Self {
        Self::zeroed()
    }
}

/// All SH coefficients of one Gaussian, band 0 first (`sh[k][c]`, k < 16).
pub type ShCoefficients = [[f32; 3]; SH_COEFFS];

/// Joins the DC term and the optional higher bands into the full coefficient set.
pub fn sh_coefficients(color: &Color, rest: Option<&ColorRest>) -> ShCoefficients {
    let mut sh = [[0.0; 3]; SH_COEFFS];
    sh[0] = color.dc;
    if let Some(rest) = rest {
        sh[1..].copy_from_slice(&rest.sh);
    }
    sh
}

/// Splits a full coefficient set into its DC term and higher bands.
pub fn split_sh(sh: &ShCoefficients) -> (Color, ColorRest) {
    let mut rest = ColorRest::default();
    rest.sh.copy_from_slice(&sh[1..]);
    (Color { dc: sh[0] }, rest)
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
    /// Σ w(t)·g(t)·Δt with Δt = t − t_i: where in time the gradient came from, relative to
    /// the centre (for `densify.clone_time: Gradient`).
    pub weighted_offset: f32,
}

/// The time range a Gaussian of a merged segment model draws in (see `tadgs segment`):
/// its opacity is multiplied by [`crate::model::deform::window_factor`], 1 inside
/// [`TimeWindow::start`, `end`], 0 outside, with a linear ramp `fade` wide centred on each
/// end. Trained models have none; neighbouring segments share an end, so their factors sum to
/// 1 and the scene cross-fades from one segment's Gaussians to the next.
///
/// Not an optimised parameter: it has no gradient and Adam state, densification copies it to
/// clones and splits (so a merged model can be trained on through the library), checkpoints do
/// not keep it, and the GPU backend refuses models that carry it.
#[derive(Component, Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct TimeWindow {
    /// Normalised time where the Gaussian fades in (the middle of the ramp).
    pub start: f32,
    /// Normalised time where it fades out (the middle of the ramp).
    pub end: f32,
    /// Width of each ramp in normalised time; 0 switches at `start` and `end` (in at
    /// `start`, out after `end`).
    pub fade: f32,
}

impl TimeWindow {
    /// A window that never hides anything.
    pub const ALWAYS: Self = Self {
        start: -1.0,
        end: 2.0,
        fade: 0.0,
    };
}

/// A Gaussian's weights w_i of the shared motion bases (`model.shared_motion`): its mean moves
/// by Σ_{b<B} w_ib·u_b(t) besides its own Fourier motion (see
/// [`crate::model::shared_motion`]).
///
/// An optimised parameter with its [`Grad`] and [`Adam`], but not one of [`param_groups!`]:
/// only the Gaussians of a model with shared motion carry it (a model without loads and
/// trains as before), it is not GPU-resident, and the model file and checkpoint hold it as a
/// tensor of their own (`motion_weights`). Densification carries it to clones and split
/// children like every component.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct MotionWeights {
    /// w_ib for b < B; the values past the model's B stay 0.
    pub w: [f32; MAX_MOTION_BASES],
}

impl Param for MotionWeights {
    const NAME: &'static str = "motion_weights";
    /// Outside [`PARAM_GROUPS`], so outside the GPU-resident layout too.
    const INDEX: usize = usize::MAX;
    type Moments = [StoredMoments; std::mem::size_of::<MotionWeights>() / 4];
}

/// The warped temporal offset Δt' = W(t − t_i) at the current time.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct WarpedTime {
    /// Raw offset Δt = t − t_i in normalised time.
    pub dt: f32,
    /// Warped offset Δt' = W(Δt) (equal to `dt` when TOW is off).
    pub dtw: f32,
}

/// The Gaussian deformed to the current time: what the splatting stage draws.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
#[repr(C)]
pub struct Deformed {
    /// World-space mean μ(t), Fourier motion included.
    pub mean: [f32; 3],
    /// Unit quaternion q(t), [w, x, y, z].
    pub rotation: [f32; 4],
    /// Per-axis standard deviations s(t) in world units (already exponentiated).
    pub scale: [f32; 3],
    /// σ(t), including the spatial opacity.
    pub opacity: f32,
    /// Linear rgb seen from the sampled camera (SH + 0.5, clamped ≥ 0).
    pub color: [f32; 3],
}

impl Deformed {
    /// A Gaussian too faded to draw at the sampled time: its opacity σ(t) (below 1/255), the
    /// origin as its mean, the identity rotation and zero scale and colour. The deformation
    /// stage writes this instead of evaluating the motion and colour of a Gaussian that
    /// nothing will draw (see [`crate::resources::DeformEveryGaussian`]).
    pub fn faded(opacity: f32) -> Self {
        Self {
            opacity,
            rotation: [1.0, 0.0, 0.0, 0.0],
            ..Self::default()
        }
    }

    /// [`Self::mean`] as a [`Vec3`].
    pub fn mean(&self) -> Vec3 {
        Vec3::from_array(self.mean)
    }
}

/// Index of this Gaussian in the splatting stage's arrays for the current iteration.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SplatSlot(pub u32);

/// The iteration through which Adam has brought this Gaussian's parameters and moments up to
/// date. Only `train.deferred_adam` reads it: there a Gaussian that received no gradient is
/// left behind until the view can next draw it or until every Gaussian catches up (see
/// [`crate::systems::adam::catch_up_drawable`] and [`crate::systems::adam::adam_step`]);
/// within the Deform stage its top bit marks the Gaussians being caught up. A checkpoint of
/// any other run records the iteration.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AdamClock(pub u32);

/// An optimised parameter component: all-`f32` plain data, declared in [`param_groups!`]
/// (or the opt-in [`MotionWeights`], which is not).
pub trait Param: Component<Mutability = Mutable> + Pod + Default + Send + Sync + 'static {
    /// Group name: logs, NaN reports, and the tensor names of model files and checkpoints.
    const NAME: &'static str;
    /// Position of the group in [`PARAM_GROUPS`] (`usize::MAX` for a group outside it).
    const INDEX: usize;
    /// `f32` values per Gaussian.
    const FLOATS: usize = std::mem::size_of::<Self>() / std::mem::size_of::<f32>();
    /// The group's Adam moments as stored: both moments of each value in one word
    /// (`[StoredMoments; FLOATS]`, see [`StoredMoments`]).
    type Moments: Pod + Send + Sync + std::fmt::Debug + PartialEq;

    /// The component's fields as one flat slice of `f32`, in declaration order.
    fn values(&self) -> &[f32] {
        bytemuck::cast_slice(std::slice::from_ref(self))
    }

    /// Mutable [`Param::values`].
    fn values_mut(&mut self) -> &mut [f32] {
        bytemuck::cast_slice_mut(std::slice::from_mut(self))
    }
}

/// The one declaration of a Gaussian's optimised parameter groups, in storage order.
///
/// Each group names its field in [`GaussianParams`] (also its [`Param::NAME`]: the tensor
/// name in model files and checkpoints), its component, and its section of the GPU-resident
/// layout (groups that share a section are stored one after the other in it: the higher SH
/// bands follow the DC term). `required` groups are spawned with every Gaussian; `optional`
/// ones only when the model uses them (the higher SH bands at SH degree above 0), and systems
/// read them as `Option<&P>`.
///
/// `param_groups!(then extra tokens)` expands to `then! { extra tokens required: [...]
/// optional: [...] }`, and [`each_param!`] to `then! { Type, Type, ..., }` (every group, in
/// order), so that each place that must handle every group (the [`Param`] impls, the spawn
/// bundle and queries, the Adam and guard systems, the GPU layout) is generated from this
/// list rather than written out again.
macro_rules! param_groups {
    ($then:ident $($extra:tt)*) => {
        $then! {
            $($extra)*
            required: [
                /// Canonical mean.
                position: $crate::components::Position, section 0;
                /// Fourier motion.
                fourier: $crate::components::Fourier, section 1;
                /// Temporal centre and scale.
                temporal: $crate::components::Temporal, section 2;
                /// Spatial opacity logit.
                opacity: $crate::components::Opacity, section 3;
                /// Rotation polynomial.
                rotation: $crate::components::Rotation, section 4;
                /// Log-scale polynomial.
                scale: $crate::components::Scale, section 5;
                /// SH colour, band 0.
                color: $crate::components::Color, section 6;
            ]
            optional: [
                /// SH colour, bands 1–3 (spawned only when the model's SH degree is above 0).
                color_rest: $crate::components::ColorRest, section 6;
            ]
        }
    };
}
pub(crate) use param_groups;

/// `each_param!(then)` expands to `then! { Position, Fourier, ..., ColorRest, }`: every
/// parameter group of [`param_groups!`] as a type, in declaration order. Import it by name
/// (`use crate::components::each_param;`): it calls itself back through [`param_groups!`].
macro_rules! each_param {
    ($then:ident) => {
        $crate::components::param_groups!(each_param @types $then)
    };
    (
        @types $then:ident
        required: [$($(#[$rdoc:meta])* $rfield:ident: $required:ty, section $rsection:literal;)*]
        optional: [$($(#[$odoc:meta])* $ofield:ident: $optional:ty, section $osection:literal;)*]
    ) => {
        $then! { $($required,)* $($optional,)* }
    };
}
pub(crate) use each_param;

/// Where a parameter group lives: [`PARAM_GROUPS`] holds one per group, in declaration order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GroupLayout {
    /// [`Param::NAME`].
    pub name: &'static str,
    /// `f32` values per Gaussian ([`Param::FLOATS`]).
    pub floats: usize,
    /// Section of the GPU-resident layout that holds it.
    pub section: usize,
    /// Spawned only when the model uses it (read as `Option<&P>`).
    pub optional: bool,
}

/// Generates, from [`param_groups!`], the [`Param`] impls, [`PARAM_GROUPS`], the
/// [`GaussianParams`] record and the tuple types that hold one Gaussian's groups.
macro_rules! declare_params {
    (
        required: [$($(#[$rdoc:meta])* $rfield:ident: $required:ty, section $rsection:literal;)*]
        optional: [$($(#[$odoc:meta])* $ofield:ident: $optional:ty, section $osection:literal;)*]
    ) => {
        /// Every parameter group, in the order of [`param_groups!`].
        pub const PARAM_GROUPS: &[GroupLayout] = &declare_params!(@layouts
            $($rfield: $required, $rsection, false;)*
            $($ofield: $optional, $osection, true;)*
        );

        declare_params!(@impl 0usize; $($rfield: $required,)* $($ofield: $optional,)*);

        /// One value of every parameter group of a Gaussian (also used for its Adam moments,
        /// which have the same shape).
        #[derive(Clone, Copy, Debug, Default, PartialEq)]
        pub struct GaussianParams {
            $($(#[$rdoc])* pub $rfield: $required,)*
            $($(#[$odoc])* pub $ofield: $optional,)*
        }

        impl GaussianParams {
            /// Copies the components of a [`ParamRefs`] query item (absent optional groups
            /// are zero).
            pub fn from_refs(refs: ParamRefs<'_>) -> Self {
                let ($($rfield,)* $($ofield,)*) = refs;
                Self {
                    $($rfield: *$rfield,)*
                    $($ofield: $ofield.copied().unwrap_or_default(),)*
                }
            }

            /// The first and second Adam moments of an [`AdamRefs`] query item, as records.
            pub fn moments_from_refs(refs: AdamRefs<'_>) -> [Self; 2] {
                let ($($rfield,)* $($ofield,)*) = refs;
                $(let $ofield = $ofield.copied().unwrap_or_default();)*
                [
                    Self { $($rfield: $rfield.m(),)* $($ofield: $ofield.m(),)* },
                    Self { $($rfield: $rfield.v(),)* $($ofield: $ofield.v(),)* },
                ]
            }

            /// The components for spawning this Gaussian with Adam moments `m` and `v`:
            /// every required group, and separately the optional ones (see
            /// [`spawn_gaussians`]).
            pub fn bundles_with_moments(
                self,
                m: &Self,
                v: &Self,
            ) -> (GaussianBundle, OptionalBundle) {
                (
                    (
                        ($(self.$rfield,)*),
                        (
                            Default::default(),
                            ($(Adam::new(&m.$rfield, &v.$rfield),)*),
                        ),
                        Default::default(),
                    ),
                    ($((self.$ofield, Grad::default(), Adam::new(&m.$ofield, &v.$ofield)),)*),
                )
            }
        }

        declare_params!(@group_of $($rfield: $required,)* $($ofield: $optional,)*);

        /// The parameters of the required groups, one tuple per Gaussian.
        pub type RequiredParams = ($($required,)*);

        /// Adam moments of every required parameter group.
        pub type AdamMoments = ($(Adam<$required>,)*);

        /// Gradients and Adam moments of every required parameter group.
        pub type OptimizerState = (($(Grad<$required>,)*), AdamMoments);

        /// The optional groups of one Gaussian with their gradients and Adam moments: spawned
        /// with its [`GaussianBundle`] when the model uses them.
        pub type OptionalBundle = ($(($optional, Grad<$optional>, Adam<$optional>),)*);

        /// [`OptionalBundle`] without the gradients (`train.fused_adam`).
        pub type OptionalMoments = ($(($optional, Adam<$optional>),)*);

        /// Drops the gradient components of an [`OptionalBundle`].
        fn optional_without_gradients(bundle: OptionalBundle) -> OptionalMoments {
            let ($($ofield,)*) = bundle;
            ($(($ofield.0, $ofield.2),)*)
        }

        /// The parameter components of one Gaussian, as a read-only query.
        pub type ParamRefs<'a> = ($(&'a $required,)* $(Option<&'a $optional>,)*);

        /// Read-only query of every Adam component of a Gaussian.
        pub type AdamRefs<'a> = ($(&'a Adam<$required>,)* $(Option<&'a Adam<$optional>>,)*);

        /// The parameter components of one Gaussian, as a writable query.
        pub type ParamMuts<'a> = ($(&'a mut $required,)* $(Option<&'a mut $optional>,)*);

        /// Writable query of every gradient component of a Gaussian.
        pub type GradMuts<'a> = ($(&'a mut Grad<$required>,)* $(Option<&'a mut Grad<$optional>>,)*);

        /// Writable query of every Adam component of a Gaussian.
        pub type AdamMuts<'a> = ($(&'a mut Adam<$required>,)* $(Option<&'a mut Adam<$optional>>,)*);

        /// Zeroed gradients and Adam moments for every required group (for new Gaussians).
        pub fn fresh_optimizer_state() -> OptimizerState {
            Default::default()
        }
    };
    (@impl $index:expr; $field:ident: $component:ty, $($rest:tt)*) => {
        impl Param for $component {
            const NAME: &'static str = stringify!($field);
            const INDEX: usize = $index;
            type Moments = [$crate::model::adam::StoredMoments; std::mem::size_of::<$component>() / 4];
        }
        declare_params!(@impl $index + 1usize; $($rest)*);
    };
    (@impl $index:expr;) => {};
    (@layouts $($field:ident: $component:ty, $section:literal, $optional:literal;)*) => {
        [$(GroupLayout {
            name: stringify!($field),
            floats: <$component as Param>::FLOATS,
            section: $section,
            optional: $optional,
        },)*]
    };
    (@group_of $($field:ident: $component:ty,)*) => {
        $(impl GroupOf<$component> for GaussianParams {
            fn group(&self) -> &$component {
                &self.$field
            }
            fn group_mut(&mut self) -> &mut $component {
                &mut self.$field
            }
        })*
    };
}

/// Access to the value of parameter group `P` in a record that holds every group
/// ([`GaussianParams`]), for code generic over the groups.
pub trait GroupOf<P: Param> {
    /// The group's value.
    fn group(&self) -> &P;
    /// The group's value, writable.
    fn group_mut(&mut self) -> &mut P;
}

param_groups!(declare_params);

/// This iteration's gradient of the loss with respect to parameter component `P`.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[repr(transparent)]
pub struct Grad<P: Param>(pub P);

/// Adam first and second moments for parameter component `P`, stored as bfloat16, both
/// moments of a value in one word (half the memory of `f32` moments; see
/// [`crate::model::adam::store_moments`] for how they are rounded). [`Adam::m`] and
/// [`Adam::v`] give them as `P`s.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[repr(transparent)]
pub struct Adam<P: Param>(P::Moments);

impl<P: Param> Adam<P> {
    /// Moments `m` and `v`, each rounded to the nearest stored value.
    pub fn new(m: &P, v: &P) -> Self {
        let mut adam = Self::zeroed();
        let pairs = m.values().iter().zip(v.values());
        for (stored, (&m, &v)) in adam.stored_mut().iter_mut().zip(pairs) {
            *stored = store_moments_nearest([m, v]);
        }
        adam
    }

    /// The first moment (running mean of the gradient).
    pub fn m(&self) -> P {
        self.moment(0)
    }

    /// The second moment (running mean of the squared gradient).
    pub fn v(&self) -> P {
        self.moment(1)
    }

    /// Moment `k` (0: m, 1: v) as values.
    fn moment(&self, k: usize) -> P {
        let mut values = P::default();
        let stored: &[StoredMoments] = bytemuck::cast_slice(std::slice::from_ref(&self.0));
        for (value, &stored) in values.values_mut().iter_mut().zip(stored) {
            *value = stored_moments(stored)[k];
        }
        values
    }

    /// The stored words, one per value.
    fn stored_mut(&mut self) -> &mut [StoredMoments] {
        bytemuck::cast_slice_mut(std::slice::from_mut(&mut self.0))
    }
}

impl<P: Param> Default for Adam<P> {
    fn default() -> Self {
        Self::zeroed()
    }
}

// SAFETY: `Grad<P>` is a transparent wrapper of the plain-data `P`; `Adam<P>` one of
// `P::Moments` (`[u32; N]`). Neither has padding or invalid bit patterns. This lets the
// optimiser step a whole column of them as one flat slice (`f32` values, `u32` moment pairs).
unsafe impl<P: Param> Zeroable for Grad<P> {}
unsafe impl<P: Param> Pod for Grad<P> {}
unsafe impl<P: Param> Zeroable for Adam<P> {}
unsafe impl<P: Param> Pod for Adam<P> {}

impl GaussianParams {
    /// All SH coefficients, band 0 first.
    pub fn sh(&self) -> ShCoefficients {
        sh_coefficients(&self.color, Some(&self.color_rest))
    }

    /// The optional groups with zeroed gradients and Adam moments, for spawning beside
    /// [`Self::bundle`].
    pub fn optional_bundle(&self) -> OptionalBundle {
        self.bundles_with_moments(&Self::default(), &Self::default())
            .1
    }

    /// The components of the required groups for spawning this Gaussian, with zeroed
    /// gradients, Adam moments and statistics.
    pub fn bundle(self) -> GaussianBundle {
        self.bundles_with_moments(&Self::default(), &Self::default())
            .0
    }
}

/// Heap bytes of the components of one Gaussian of a model of SH degree `sh_degree`, with
/// or without its gradient components (`train.fused_adam` does without them).
pub fn gaussian_bytes(sh_degree: u32, gradients: bool) -> usize {
    use std::mem::size_of;
    match (sh_degree > 0, gradients) {
        (true, true) => size_of::<GaussianBundle>() + size_of::<OptionalBundle>(),
        (false, true) => size_of::<GaussianBundle>(),
        (true, false) => size_of::<BundleWithoutGradients>() + size_of::<OptionalMoments>(),
        (false, false) => size_of::<BundleWithoutGradients>(),
    }
}

/// Spawns Gaussians, with their optional groups (the higher SH bands) only when `sh_degree`
/// (the model's highest degree) is above 0, and without their gradient components when the
/// world's [`Settings`](crate::resources::Settings) fuse Adam
/// ([`crate::scene::TrainConfig::fuses_adam`]; the bundles' gradient components are then
/// dropped).
pub fn spawn_gaussians(
    world: &mut World,
    sh_degree: u32,
    gaussians: impl IntoIterator<Item = (GaussianBundle, OptionalBundle)>,
) {
    spawn_gaussians_with(
        world,
        sh_degree,
        gaussians
            .into_iter()
            .map(|(bundle, optional)| (bundle, optional, ())),
    );
}

/// [`spawn_gaussians`] with `extra` components on each Gaussian (a merged model's
/// [`TimeWindow`]).
pub fn spawn_gaussians_with<E: Bundle<Effect: NoBundleEffect>>(
    world: &mut World,
    sh_degree: u32,
    gaussians: impl IntoIterator<Item = (GaussianBundle, OptionalBundle, E)>,
) {
    let gaussians = gaussians.into_iter();
    let gradients = !world
        .get_resource::<crate::resources::Settings>()
        .is_some_and(|s| s.train.fuses_adam());
    match (sh_degree > 0, gradients) {
        (true, true) => {
            world.spawn_batch(gaussians);
        }
        (false, true) => {
            world.spawn_batch(gaussians.map(|(bundle, _, extra)| (bundle, extra)));
        }
        (true, false) => {
            world.spawn_batch(gaussians.map(|(bundle, optional, extra)| {
                (
                    without_gradients(bundle),
                    optional_without_gradients(optional),
                    extra,
                )
            }));
        }
        (false, false) => {
            world.spawn_batch(
                gaussians.map(|(bundle, _, extra)| (without_gradients(bundle), extra)),
            );
        }
    }
}

/// A Gaussian's components without its gradient components.
fn without_gradients((params, (_, moments), state): GaussianBundle) -> BundleWithoutGradients {
    (params, moments, state)
}

/// Every component of one Gaussian but the optional groups ([`OptionalBundle`]).
pub type GaussianBundle = (RequiredParams, OptimizerState, GaussianState);

/// [`GaussianBundle`] without the gradient components (`train.fused_adam`).
pub type BundleWithoutGradients = (RequiredParams, AdamMoments, GaussianState);

/// A Gaussian's components besides its parameters and optimiser state: densification
/// statistics, Adam clock and the stages' per-iteration results.
pub type GaussianState = (GradAccum, WarpedTime, Deformed, SplatSlot, AdamClock);
