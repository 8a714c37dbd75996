// Generated from the parameter declaration (`param_groups!` in src/components.rs) by
// src/layout.rs; do not edit. Regenerate with
//   TADGS_BLESS=1 cargo test --release --test gpu_layout

const FOURIER_TERMS: u32 = 4u;
const SH_COEFFS: u32 = 16u;
const PARAM_FLOATS: u32 = 97u;
const WIDTH_POSITION: u32 = 3u;
const PREFIX_POSITION: u32 = 0u;
const WIDTH_FOURIER: u32 = 28u;
const PREFIX_FOURIER: u32 = 3u;
const WIDTH_TEMPORAL: u32 = 3u;
const PREFIX_TEMPORAL: u32 = 31u;
const WIDTH_OPACITY: u32 = 1u;
const PREFIX_OPACITY: u32 = 34u;
const WIDTH_ROTATION: u32 = 8u;
const PREFIX_ROTATION: u32 = 35u;
const WIDTH_SCALE: u32 = 6u;
const PREFIX_SCALE: u32 = 43u;
const WIDTH_COLOR: u32 = 48u;
const PREFIX_COLOR: u32 = 49u;
const OFFSET_POSITION: u32 = 0u;
const OFFSET_FOURIER: u32 = 0u;
const OFFSET_TEMPORAL: u32 = 0u;
const OFFSET_OPACITY: u32 = 0u;
const OFFSET_ROTATION: u32 = 0u;
const OFFSET_SCALE: u32 = 0u;
const OFFSET_COLOR: u32 = 0u;
const OFFSET_COLOR_REST: u32 = 3u;
