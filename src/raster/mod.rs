//! CPU tile rasterizer, forward and backward: the reference backend.
//!
//! Splats (projected 2D Gaussians) are binned into 16×16 tiles, sorted by depth per tile and
//! alpha-blended front to back with the 3DGS constants (SPEC §4). The backward pass walks each
//! pixel's contributors back to front and writes one gradient per (tile, splat) pair; those
//! partial sums are then reduced per splat, so no atomics are needed and the result is
//! deterministic.
//!
//! Speed: tiles run in parallel (rayon); inside a tile the pixel loops work on whole 16-pixel
//! rows with branch-free selects so that the compiler vectorises them, and they are compiled
//! three times, for the baseline x86-64 target, for AVX2 and for AVX-512, with the choice made
//! at run time ([`simd_level`]). Every buffer is reused across calls.

mod backward;
mod binning;
mod forward;

use glam::Vec2;

use crate::io::image::Image;

pub use binning::TileBins;
pub use forward::PairCounts;

/// Tile side in pixels.
pub const TILE: usize = 16;
/// Pixels per tile.
pub const TILE_PIXELS: usize = TILE * TILE;
/// Contributions below this alpha are skipped.
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Alpha is clamped to this value.
pub const ALPHA_MAX: f32 = 0.99;
/// A pixel stops once its transmittance would fall below this.
pub const TRANSMITTANCE_MIN: f32 = 1e-4;

/// A projected Gaussian ready to be blended.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Splat {
    /// Centre in pixel coordinates (pixel (x, y) has its centre at (x + 0.5, y + 0.5)).
    pub mean2d: Vec2,
    /// (a, b, c) of the inverse 2D covariance: power = −½(a·dx² + c·dy²) − b·dx·dy.
    pub conic: [f32; 3],
    /// Camera-space depth z (sort key within a tile).
    pub depth: f32,
    /// Opacity σ(t) in [0, 1]; alpha = min(0.99, opacity·G).
    pub opacity: f32,
    /// Linear rgb.
    pub color: [f32; 3],
    /// Half-size in pixels of the screen box it covers.
    pub extent: Vec2,
    /// False for splats culled by projection: they cover no tile.
    pub visible: bool,
}

/// Gradient of the loss with respect to a splat's blended quantities.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SplatGrad {
    /// dL/d[`Splat::mean2d`], in pixel units.
    pub mean2d: Vec2,
    /// dL/d[`Splat::conic`] (a, b, c).
    pub conic: [f32; 3],
    /// dL/d[`Splat::opacity`].
    pub opacity: f32,
    /// dL/d[`Splat::color`].
    pub color: [f32; 3],
}

impl SplatGrad {
    fn add(&mut self, other: &SplatGrad) {
        self.mean2d += other.mean2d;
        for i in 0..3 {
            self.conic[i] += other.conic[i];
            self.color[i] += other.color[i];
        }
        self.opacity += other.opacity;
    }
}

/// What the pixel loops read of a splat, packed once per frame in one cache line.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
struct Packed {
    mean: [f32; 2],
    conic: [f32; 3],
    opacity: f32,
    /// The exponent, in powers of two, below which alpha < 1/255 ([`min_power`] · log2 e).
    min_exp2: f32,
    color: [f32; 3],
    extent: [f32; 2],
    /// Row spans of the ellipse where the exponent reaches `min_power` − 0.01: at vertical
    /// offset dy the columns are centre − (b/a)·dy ± sqrt(s0 − s1·dy²); `span` = [s0, s1, b/a].
    span: [f32; 3],
}

/// Bytes of one splat as the pixel loops read it (for memory estimates).
pub(crate) const PACKED_SPLAT_BYTES: usize = size_of::<Packed>();

impl Packed {
    #[inline(always)]
    fn new(s: &Splat) -> Self {
        let [a, b, c] = s.conic;
        let min_power = min_power(s.opacity);
        // power ≥ p ⇔ a·dx² + 2b·dy·dx + c·dy² + 2p ≤ 0, a quadratic in dx; the margin below
        // min_power covers rounding. A conic that is not positive definite gets no shortcut.
        let span = if a > 0.0 {
            let p = min_power - 0.01;
            [-2.0 * p / a, (a * c - b * b) / (a * a), b / a]
        } else {
            [f32::INFINITY, 0.0, 0.0]
        };
        Self {
            mean: s.mean2d.to_array(),
            conic: s.conic,
            opacity: s.opacity,
            min_exp2: min_power * std::f32::consts::LOG2_E,
            color: s.color,
            extent: s.extent.to_array(),
            span,
        }
    }
}

/// Rasterizer state reused across iterations: tile bins and the per-pixel forward results
/// the backward pass needs.
#[derive(Default)]
pub struct Rasterizer {
    bins: TileBins,
    /// The splats of the last forward pass, packed for the pixel loops.
    packed: Vec<Packed>,
    /// Final transmittance per pixel, tile-major.
    final_transmittance: Vec<f32>,
    /// Per pixel (tile-major): number of tile entries up to and including the last one blended.
    contributors: Vec<u32>,
    /// Colour of the last forward pass, per tile: 256 red, 256 green, 256 blue values.
    tile_color: Vec<f32>,
    /// Gradient partial sums of the entries the last backward pass walked: tile t's first
    /// entries (in depth order) at `walked_offsets[t]..walked_offsets[t + 1]`.
    entry_grads: Vec<SplatGrad>,
    /// Prefix sums over the tiles of how many entries the backward walks in each (the largest
    /// contributor count of its pixels), one more than tiles.
    walked_offsets: Vec<u32>,
    /// Per-splat gradient sums of the second half of the tiles in the backward's reduction.
    lower_grads: Vec<SplatGrad>,
    background: [f32; 3],
}

/// Rendered image and coverage (alpha = 1 − final transmittance), row-major.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    /// The blended colour, background included.
    pub image: Image,
    /// Coverage per pixel in [0, 1], row-major.
    pub alpha: Vec<f32>,
}

impl Default for RenderOutput {
    fn default() -> Self {
        Self {
            image: Image::filled(0, 0, [0.0; 3]),
            alpha: Vec::new(),
        }
    }
}

impl Rasterizer {
    /// An empty rasterizer; buffers are allocated on first use.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of (tile, splat) pairs in the last forward pass.
    pub fn intersections(&self) -> usize {
        self.bins.entry_count()
    }

    /// Heap bytes held by the rasterizer's reusable buffers.
    pub fn heap_bytes(&self) -> usize {
        fn bytes<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        self.bins.heap_bytes()
            + bytes(&self.packed)
            + bytes(&self.final_transmittance)
            + bytes(&self.contributors)
            + bytes(&self.tile_color)
            + bytes(&self.entry_grads)
            + bytes(&self.walked_offsets)
            + bytes(&self.lower_grads)
    }

    fn tiles_x(&self) -> usize {
        self.bins.tiles_x
    }
}

/// e^x for x ≤ 0 (the Gaussian falloff), relative error below 2e-6 (1e-7 from the polynomial,
/// the rest from rounding x·log2 e in f32); see [`exp2_falloff`].
#[inline(always)]
pub fn exp_falloff(x: f32) -> f32 {
    exp2_falloff::<false>(x * std::f32::consts::LOG2_E)
}

/// a·b + c: one fused instruction in the kernels compiled with FMA (`FUSED`), else a multiply
/// and an add (`mul_add` without the instruction is a slow libm call).
#[inline(always)]
fn mul_add<const FUSED: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FUSED { a.mul_add(b, c) } else { a * b + c }
}

/// 2^t for t ≤ 0: a power-of-two split and a degree-5 polynomial (relative error 1e-7 on its
/// interval), branch-free so the per-pixel loops vectorise (libm's `exp2f` is a call). It is
/// the longest chain of dependent steps in the pixel loops, so it is kept short: Horner's rule
/// with fused multiply-adds where the CPU has them.
#[inline(always)]
fn exp2_falloff<const FUSED: bool>(t: f32) -> f32 {
    let t = t.max(-126.0);
    // Round to nearest by adding and removing 1.5·2^23: the sum holds n = round(t) in its low
    // mantissa bits (no libm call, no float-to-int conversion; vectorises).
    const ROUND: f32 = 12_582_912.0;
    let shifted = t + ROUND;
    let n = shifted - ROUND;
    let f = t - n; // in [−½, ½]
    // 2^f − 1 = f·q(f), q the degree-4 polynomial that minimises the relative error of 2^f on
    // [−½, ½] (9.2e-8); the constant term stays exactly 1, so 2^0 = 1.
    let q = mul_add::<FUSED>(0.001_326_472_5, f, 0.009_671_513);
    let q = mul_add::<FUSED>(q, f, 0.055_507_337);
    let q = mul_add::<FUSED>(q, f, 0.240_222_42);
    // A fitted coefficient that happens to lie near ln 2, not ln 2 itself.
    #[allow(clippy::approx_constant)]
    let q = mul_add::<FUSED>(q, f, 0.693_147);
    let p = mul_add::<FUSED>(q, f, 1.0);
    // 2^n from the exponent bits: n + 127 shifted into place (n ≥ −126 by the clamp above).
    let n_bits = shifted.to_bits().wrapping_sub(ROUND.to_bits());
    f32::from_bits(n_bits.wrapping_add(127) << 23) * p
}

/// Asks the CPU to start loading the splat an entry loop will reach a few entries later: tile
/// lists jump around the splat array, and that first load is otherwise a cache miss the loop
/// waits on.
#[inline(always)]
fn prefetch_entry(splats: &[Packed], entries: &[u32], k: usize) {
    if let Some(&s) = entries.get(k) {
        prefetch(splats, s as usize);
    }
}

/// Asks the CPU to start loading `items[index]` (when in bounds) into its cache, for a loop
/// that reads it a few steps later.
#[inline(always)]
fn prefetch<T>(items: &[T], index: usize) {
    if let Some(item) = items.get(index) {
        prefetch_lines(std::slice::from_ref(item));
    }
}

/// Asks the CPU to bring every cache line of `values` in ahead of their use (a no-op off
/// x86-64).
#[inline(always)]
pub(crate) fn prefetch_lines<T>(values: &[T]) {
    #[cfg(target_arch = "x86_64")]
    {
        let start = values.as_ptr().cast::<u8>();
        for offset in (0..std::mem::size_of_val(values)).step_by(64) {
            // SAFETY: a prefetch never faults, and the address is inside `values`.
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                    start.add(offset).cast(),
                )
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = values;
}

/// How many entries ahead [`prefetch_entry`] looks.
const PREFETCH_AHEAD: usize = 4;

/// Tile-local pixel range [x0, x1) × [y0, y1) of a splat's screen box, clipped to the tile:
/// outside the box the splat's alpha is below 1/255 (see [`Splat::extent`]), so those pixels
/// are skipped.
#[inline(always)]
fn box_in_tile(mean: [f32; 2], extent: [f32; 2], origin: (usize, usize)) -> [usize; 4] {
    let local = |centre: f32, extent: f32, start: usize| {
        let lo = (centre - extent - 0.5 - start as f32).floor().max(0.0) as usize;
        let hi =
            ((centre + extent - 0.5 - start as f32).ceil() + 1.0).clamp(0.0, TILE as f32) as usize;
        (lo.min(TILE), hi)
    };
    let (x0, x1) = local(mean[0], extent[0], origin.0);
    let (y0, y1) = local(mean[1], extent[1], origin.1);
    [x0, x1, y0, y1.max(y0)]
}

/// The exponent below which a splat's alpha is under 1/255 (with a little slack for rounding;
/// the alpha test itself follows).
#[inline]
pub(crate) fn min_power(opacity: f32) -> f32 {
    (ALPHA_MIN / opacity).ln() - 1e-4
}

/// `a` where `keep`, else `b`: a select the vectoriser turns into a blend.
#[inline(always)]
fn pick(keep: bool, a: f32, b: f32) -> f32 {
    if keep { a } else { b }
}

/// Pixels per lane group: a tile row is two groups, one AVX2 register each (one AVX-512
/// register holds a row).
const LANES: usize = 8;
/// Lane groups per tile.
const GROUPS: usize = TILE_PIXELS / LANES;

/// For every tile row, the columns of the box columns [x0, x1) that can hold drawn pixels of
/// the splat: where the exponent reaches `min_power` (minus a margin for rounding), plus a
/// pixel each side. The per-pixel test still decides; this only skips lane groups that cannot
/// pass it. A row that misses the ellipse gets an empty span. All sixteen rows are computed at
/// once in vector lanes, so a splat pays for its spans once per tile instead of once per row;
/// so are the per-row and per-column terms of its exponent, which [`falloff_pair`] then only
/// loads.
/// `spans` is reused from entry to entry (its idle row is never written, so it stays empty):
/// a fresh one per entry would cost a memset of its 540 bytes.
#[inline(always)]
fn row_spans(spans: &mut RowSpans, sp: &Packed, origin: (usize, usize), (x0, x1): (usize, usize)) {
    let [s0, s1, b_over_a] = sp.span;
    let (x0f, x1f) = (x0 as f32, x1 as f32);
    let (origin_x, origin_y) = (origin.0 as f32, origin.1 as f32);
    // The exponent in powers of two, e2 = (qa·dx + qb·dy)·dx + qc·dy², is two multiply-adds
    // per pixel once the row's terms qb·dy and qc·dy² are known.
    let [_, b, c] = sp.conic;
    let log2e = std::f32::consts::LOG2_E;
    let (qb, qc) = (-b * log2e, -0.5 * c * log2e);
    // Pixel centres are at integer + 0.5 (integers are exact in f32).
    for (x, dx) in spans.dx.iter_mut().enumerate() {
        *dx = (origin_x + x as f32) + 0.5 - sp.mean[0];
    }
    for y in 0..TILE {
        let dy = (origin_y + y as f32) + 0.5 - sp.mean[1];
        spans.dy[y] = dy;
        spans.linear[y] = qb * dy;
        spans.constant[y] = qc * dy * dy;
        let q = s0 - s1 * dy * dy;
        let half = q.max(0.0).sqrt();
        // Tile-local column of dx = 0 (pixel x has its centre at x + 0.5).
        let centre = sp.mean[0] - 0.5 - origin_x - b_over_a * dy;
        // max/min return the other operand for NaN, so both ends land in [x0, x1].
        let lo = ((centre - half).floor() - 1.0).max(x0f).min(x1f);
        let hi = ((centre + half).ceil() + 2.0).min(x1f).max(lo);
        let hi = if q < 0.0 { lo } else { hi };
        spans.lo[y] = lo;
        spans.hi[y] = hi;
    }
}

/// Column spans [lo, hi) per tile row (see [`row_spans`]), whole numbers in [0, 16] held as
/// floats for the pixel loops' compares, and the terms of the splat's exponent per row and per
/// column. The extra row, always empty, is the one of the idle slot ([`IDLE`]).
#[derive(Default)]
struct RowSpans {
    lo: [f32; TILE + 1],
    hi: [f32; TILE + 1],
    /// Per row: dy, qb·dy and qc·dy² (see [`row_spans`]).
    dy: [f32; TILE + 1],
    linear: [f32; TILE + 1],
    constant: [f32; TILE + 1],
    /// Per column: dx.
    dx: [f32; TILE],
}

/// A set of a tile's lane groups, bit r for group r (tile rows are two groups each).
type GroupBits = u32;
const _: () = assert!(GROUPS == GroupBits::BITS as usize);

/// Slot of the per-pixel state arrays that belongs to no pixel: the pixel loops take lane
/// groups two at a time, and a splat that reaches an odd number of groups pairs its last one
/// with this slot, which draws nothing (no lanes in its span, no live or walked pixels).
const IDLE: usize = GROUPS;
/// Slots of the per-pixel state arrays: one per lane group, plus [`IDLE`].
const SLOTS: usize = GROUPS + 1;

impl RowSpans {
    /// The lane groups of rows [y0, y1) that the spans reach. The pixel loops walk these bits
    /// instead of looping over rows and their groups: one loop with one exit per splat keeps
    /// the branch predictor right, and a mispredicted branch would throw away the overlapping
    /// work of the next groups.
    #[inline(always)]
    fn groups(&self, y0: usize, y1: usize) -> GroupBits {
        let mut bits = 0;
        for y in 0..TILE {
            let (lo, hi) = (self.lo[y], self.hi[y]);
            let row = (y >= y0) & (y < y1) & (lo < hi);
            let first = row & (lo < LANES as f32);
            let second = row & (hi > LANES as f32);
            bits |= ((first as GroupBits) | (second as GroupBits) << 1) << (2 * y);
        }
        bits
    }
}

/// Two lane groups worked on together, as one 16-lane vector: two independent chains of
/// arithmetic keep the CPU busy while each waits on the latency of the other (the exponential
/// alone is a chain of a dozen dependent steps). With `WIDE` (kernels whose registers hold all
/// sixteen lanes) the two groups are always the two halves of one tile row, which lie side by
/// side in the state arrays, so the pair loads and stores as one register.
#[derive(Clone, Copy)]
struct Pair<const WIDE: bool>([usize; 2]);

impl<const WIDE: bool> Pair<WIDE> {
    /// The two groups' lanes of a per-group state array, side by side.
    #[inline(always)]
    fn get<T: Copy + Default>(self, state: &[[T; LANES]; SLOTS]) -> [T; PAIR] {
        let mut out = [T::default(); PAIR];
        if WIDE {
            let first = self.0[0] * LANES;
            out.copy_from_slice(&state.as_flattened()[first..first + PAIR]);
        } else {
            out[..LANES].copy_from_slice(&state[self.0[0]]);
            out[LANES..].copy_from_slice(&state[self.0[1]]);
        }
        out
    }

    /// Writes `value` back into the two groups' lanes of `state`.
    #[inline(always)]
    fn set<T: Copy>(self, state: &mut [[T; LANES]; SLOTS], value: [T; PAIR]) {
        if WIDE {
            let first = self.0[0] * LANES;
            state.as_flattened_mut()[first..first + PAIR].copy_from_slice(&value);
        } else {
            state[self.0[0]].copy_from_slice(&value[..LANES]);
            state[self.0[1]].copy_from_slice(&value[LANES..]);
        }
    }
}

/// The groups in a [`GroupBits`] set, lowest first, two at a time; an odd one out is paired
/// with [`IDLE`]. With `WIDE`, whole tile rows instead: every row with a group in the set, as
/// the pair of its two groups (the lanes of the group not in the set draw nothing, as the row
/// span leaves them out). An iterator rather than a closure: a closure is a function of its
/// own that may stay out of line, and then it would not get the vector code of the kernel
/// that calls it.
struct Pairs<const WIDE: bool>(GroupBits);

impl<const WIDE: bool> Iterator for Pairs<WIDE> {
    type Item = Pair<WIDE>;

    #[inline(always)]
    fn next(&mut self) -> Option<Pair<WIDE>> {
        let bits = self.0;
        if bits == 0 {
            return None;
        }
        if WIDE {
            let first = bits.trailing_zeros() as usize & !1;
            self.0 = bits & !(0b11 << first);
            return Some(Pair([first, first + 1]));
        }
        let first = bits.trailing_zeros() as usize;
        let rest = bits & (bits - 1);
        let second = if rest == 0 {
            IDLE
        } else {
            rest.trailing_zeros() as usize
        };
        self.0 = rest & rest.wrapping_sub(1);
        Some(Pair([first, second]))
    }
}

/// A splat's falloff over a [`Pair`] of lane groups: per lane the offsets (dx, dy) of the
/// pixel centre from the splat's centre and the Gaussian G, with G = 0 where the splat is not
/// drawn (outside the lanes of its row span, exponent outside [min_power, 0], or alpha below
/// 1/255); a drawn pixel has alpha ≥ 1/255, so G > 0 is the drawn mask. Forward and backward
/// share it so they agree on every pixel.
struct Falloff {
    dx: F16,
    dy: F16,
    gauss: F16,
}

#[inline(always)]
fn falloff_pair<const FUSED: bool, const WIDE: bool>(
    sp: &Packed,
    spans: &RowSpans,
    pair: Pair<WIDE>,
) -> Falloff {
    let (mut dx, mut dy, mut gauss) = ([0f32; PAIR], [0f32; PAIR], [0f32; PAIR]);
    let qa = -0.5 * sp.conic[0] * std::f32::consts::LOG2_E;
    // Per lane: its row's terms, its column and its offset. Each half is filled by a loop of
    // its own from scalars (broadcasts): indexing the halves inside the lane loop would make
    // the wide kernels gather.
    let (mut linear, mut constant) = ([0f32; PAIR], [0f32; PAIR]);
    let (mut lo, mut hi, mut columns) = ([0f32; PAIR], [0f32; PAIR], [0f32; PAIR]);
    let halves = if WIDE {
        // One tile row: the same row terms, sixteen consecutive columns.
        [(pair.0[0] / 2, 0), (pair.0[0] / 2, LANES)]
    } else {
        pair.0.map(|r| (r / 2, (r % 2) * LANES))
    };
    for (half, (y, start)) in halves.into_iter().enumerate() {
        let lanes = half * LANES..(half + 1) * LANES;
        dy[lanes.clone()].fill(spans.dy[y]);
        linear[lanes.clone()].fill(spans.linear[y]);
        constant[lanes.clone()].fill(spans.constant[y]);
        lo[lanes.clone()].fill(spans.lo[y]);
        hi[lanes.clone()].fill(spans.hi[y]);
        columns[lanes.clone()].copy_from_slice(&COLUMNS[start..start + LANES]);
        dx[lanes].copy_from_slice(&spans.dx[start..start + LANES]);
    }
    for i in 0..PAIR {
        let e2 = mul_add::<FUSED>(mul_add::<FUSED>(qa, dx[i], linear[i]), dx[i], constant[i]);
        let g = exp2_falloff::<FUSED>(e2);
        let in_span = columns[i] >= lo[i] && columns[i] < hi[i];
        // Below `min_exp2` alpha < 1/255; a positive exponent is numerical noise.
        let drawn = in_span & !(e2 > 0.0) & !(e2 < sp.min_exp2) & (sp.opacity * g >= ALPHA_MIN);
        gauss[i] = pick(drawn, g, 0.0);
    }
    Falloff {
        dx: F16(dx),
        dy: F16(dy),
        gauss: F16(gauss),
    }
}

/// Tile-local column numbers as floats.
const COLUMNS: [f32; TILE] = {
    let mut columns = [0f32; TILE];
    let mut x = 0;
    while x < TILE {
        columns[x] = x as f32;
        x += 1;
    }
    columns
};

/// Lanes of a [`Pair`]: two groups of eight pixels.
const PAIR: usize = 2 * LANES;

/// Sixteen f32 lanes with element-wise arithmetic written as plain loops, which the compiler
/// turns into one to four vector instructions each (one AVX-512 register, two AVX2 or four SSE
/// ones). Long chains of array code are not always vectorised; these small steps always are.
#[derive(Clone, Copy, Debug, Default)]
#[repr(transparent)]
struct F16([f32; PAIR]);

/// Lane masks for [`F16`]: all bits set where true.
#[derive(Clone, Copy, Debug)]
#[repr(transparent)]
struct M16([u32; PAIR]);

macro_rules! lanewise {
    ($a:expr, $b:expr, |$x:ident, $y:ident| $e:expr) => {{
        let (a, b) = ($a, $b);
        let mut out = [Default::default(); PAIR];
        for i in 0..PAIR {
            let ($x, $y) = (a[i], b[i]);
            out[i] = $e;
        }
        out
    }};
}

impl std::ops::Add for F16 {
    type Output = F16;
    #[inline(always)]
    fn add(self, o: F16) -> F16 {
        F16(lanewise!(self.0, o.0, |x, y| x + y))
    }
}

impl std::ops::Sub for F16 {
    type Output = F16;
    #[inline(always)]
    fn sub(self, o: F16) -> F16 {
        F16(lanewise!(self.0, o.0, |x, y| x - y))
    }
}

impl std::ops::Mul for F16 {
    type Output = F16;
    #[inline(always)]
    fn mul(self, o: F16) -> F16 {
        F16(lanewise!(self.0, o.0, |x, y| x * y))
    }
}

impl std::ops::Div for F16 {
    type Output = F16;
    #[inline(always)]
    fn div(self, o: F16) -> F16 {
        F16(lanewise!(self.0, o.0, |x, y| x / y))
    }
}

impl std::ops::BitAnd for M16 {
    type Output = M16;
    #[inline(always)]
    fn bitand(self, o: M16) -> M16 {
        M16(lanewise!(self.0, o.0, |x, y| x & y))
    }
}

impl F16 {
    #[inline(always)]
    fn splat(v: f32) -> F16 {
        F16([v; PAIR])
    }

    #[inline(always)]
    fn lt(self, o: F16) -> M16 {
        M16(lanewise!(self.0, o.0, |x, y| if x < y { !0 } else { 0 }))
    }

    /// `self` where `m`, else `other`.
    #[inline(always)]
    fn select(self, m: M16, other: F16) -> F16 {
        let mut out = [0f32; PAIR];
        for i in 0..PAIR {
            let bits = (self.0[i].to_bits() & m.0[i]) | (other.0[i].to_bits() & !m.0[i]);
            out[i] = f32::from_bits(bits);
        }
        F16(out)
    }

    #[inline(always)]
    fn sum(self) -> f32 {
        self.0.iter().sum()
    }

    /// self·b + c, fused where the kernel has FMA (see [`mul_add`]).
    #[inline(always)]
    fn mul_add<const FUSED: bool>(self, b: F16, c: F16) -> F16 {
        let mut out = [0f32; PAIR];
        for i in 0..PAIR {
            out[i] = mul_add::<FUSED>(self.0[i], b.0[i], c.0[i]);
        }
        F16(out)
    }
}

impl M16 {
    /// Lanes set in `self` but not in `other`.
    #[inline(always)]
    fn and_not(self, other: M16) -> M16 {
        M16(lanewise!(self.0, other.0, |x, y| x & !y))
    }

    /// `value` where set, else `other`, for integer lanes.
    #[inline(always)]
    fn select_u32(self, value: u32, other: [u32; PAIR]) -> [u32; PAIR] {
        lanewise!(self.0, other, |m, o| (value & m) | (o & !m))
    }

    /// Lanes where `k < values[i]`.
    #[inline(always)]
    fn below(k: u32, values: [u32; PAIR]) -> M16 {
        let mut out = [0u32; PAIR];
        for i in 0..PAIR {
            out[i] = if k < values[i] { !0 } else { 0 };
        }
        M16(out)
    }
}

/// Defines a pixel-loop function compiled three times, for AVX-512, for AVX2 + FMA and for the
/// baseline target, that runs the best version this CPU has ([`simd_level`]). The body gets two
/// constants: `FUSED`, whether it may use fused multiply-adds (see [`mul_add`]), and `WIDE`,
/// whether its vector registers hold sixteen lanes (a whole tile row, see [`Pair`]).
macro_rules! simd_kernel {
    ($(#[$meta:meta])* fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $body:block) => {
        $(#[$meta])*
        #[allow(clippy::too_many_arguments)]
        fn $name($($arg: $ty),*) {
            #[inline(always)]
            #[allow(clippy::too_many_arguments)]
            fn body<const FUSED: bool, const WIDE: bool>($($arg: $ty),*) $body

            #[cfg(target_arch = "x86_64")]
            {
                use $crate::raster::SimdLevel;
                #[target_feature(enable = "avx512f,avx512vl,avx512bw,avx512dq,avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                fn avx512($($arg: $ty),*) {
                    body::<true, true>($($arg),*)
                }
                #[target_feature(enable = "avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                fn avx2($($arg: $ty),*) {
                    body::<true, false>($($arg),*)
                }
                match $crate::raster::simd_level() {
                    // SAFETY: the CPU supports these features (checked at run time).
                    SimdLevel::Avx512 => return unsafe { avx512($($arg),*) },
                    // SAFETY: as above.
                    SimdLevel::Avx2 => return unsafe { avx2($($arg),*) },
                    SimdLevel::Baseline => {}
                }
            }
            body::<false, false>($($arg),*)
        }
    };
}
pub(crate) use simd_kernel;

/// The instruction sets the pixel loops are compiled for, chosen at run time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum SimdLevel {
    /// The baseline x86-64 target (SSE2), or any other architecture.
    Baseline,
    /// AVX2 with fused multiply-adds: eight lanes per register.
    Avx2,
    /// AVX-512 (F, VL, BW, DQ) with fused multiply-adds: sixteen lanes per register.
    Avx512,
}

impl SimdLevel {
    /// The best level this CPU supports.
    pub fn detected() -> SimdLevel {
        #[cfg(target_arch = "x86_64")]
        {
            let avx2 = is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
            let avx512 = is_x86_feature_detected!("avx512f")
                && is_x86_feature_detected!("avx512vl")
                && is_x86_feature_detected!("avx512bw")
                && is_x86_feature_detected!("avx512dq");
            if avx2 && avx512 {
                return SimdLevel::Avx512;
            }
            if avx2 {
                return SimdLevel::Avx2;
            }
        }
        SimdLevel::Baseline
    }

    /// The level `TADGS_SIMD` asks for (`baseline`, `avx2` or `avx512`), if it names one.
    pub fn requested() -> Option<SimdLevel> {
        match std::env::var("TADGS_SIMD").ok()?.as_str() {
            "baseline" => Some(SimdLevel::Baseline),
            "avx2" => Some(SimdLevel::Avx2),
            "avx512" => Some(SimdLevel::Avx512),
            _ => None,
        }
    }

    /// How the level is shown in reports.
    pub fn name(self) -> &'static str {
        match self {
            SimdLevel::Baseline => "baseline",
            SimdLevel::Avx2 => "x86-64 AVX2 + FMA",
            SimdLevel::Avx512 => "x86-64 AVX-512 + FMA",
        }
    }
}

/// The level the pixel loops run at: the best this CPU has, or a lower one that `TADGS_SIMD`
/// asks for (to compare them; a level the CPU lacks is never chosen). Decided once.
#[inline]
pub fn simd_level() -> SimdLevel {
    static LEVEL: std::sync::OnceLock<SimdLevel> = std::sync::OnceLock::new();
    *LEVEL.get_or_init(|| {
        let detected = SimdLevel::detected();
        SimdLevel::requested().map_or(detected, |requested| requested.min(detected))
    })
}

#[cfg(test)]
mod tests;
