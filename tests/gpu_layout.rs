//! The shaders' parameter layout (`shaders/param_layout.wgsl`) is the one the Rust declaration
//! of the parameter groups gives (`tadgs::layout::wgsl_layout`). Regenerate the file with
//! `TADGS_BLESS=1 cargo test --release --test gpu_layout`.

use tadgs::layout::wgsl_layout;

const PATH: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/shaders/param_layout.wgsl");

/// Fails when a parameter group, its width or its section changed in Rust but the WGSL
/// constants the kernels index the buffers with did not (or the file was edited by hand).
#[test]
fn wgsl_layout_matches_the_parameter_declaration() {
    let generated = wgsl_layout();
    if std::env::var_os("TADGS_BLESS").is_some() {
        std::fs::write(PATH, &generated).expect("write shaders/param_layout.wgsl");
        return;
    }
    let file = std::fs::read_to_string(PATH).expect("read shaders/param_layout.wgsl");
    assert!(
        file == generated,
        "shaders/param_layout.wgsl disagrees with the parameter declaration; run \
         TADGS_BLESS=1 cargo test --release --test gpu_layout\n--- file\n{file}\n--- declaration\n{generated}"
    );
}

/// The generated constants are the layout the kernels were written for (the values the
/// hand-written constants had): a change to the declaration shows here too.
#[test]
fn the_generated_constants_are_the_kernels_layout() {
    let generated = wgsl_layout();
    for line in [
        "const PARAM_FLOATS: u32 = 97u;",
        "const WIDTH_POSITION: u32 = 3u;",
        "const PREFIX_FOURIER: u32 = 3u;",
        "const WIDTH_FOURIER: u32 = 28u;",
        "const PREFIX_TEMPORAL: u32 = 31u;",
        "const PREFIX_OPACITY: u32 = 34u;",
        "const PREFIX_ROTATION: u32 = 35u;",
        "const PREFIX_SCALE: u32 = 43u;",
        "const PREFIX_COLOR: u32 = 49u;",
        "const WIDTH_COLOR: u32 = 48u;",
        "const OFFSET_COLOR_REST: u32 = 3u;",
    ] {
        assert!(generated.contains(line), "missing `{line}` in\n{generated}");
    }
}
