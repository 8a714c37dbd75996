//! The parameter layout of the GPU-resident buffers and of the model files, derived from the
//! declaration of the parameter groups ([`crate::components::param_groups!`] /
//! [`PARAM_GROUPS`]): one section per stored group, the groups that share a section stored one
//! after the other in it (the higher SH bands after the DC term, so files and kernels see one
//! 48-value colour). The GPU buffers hold the sections as structure of arrays; model files and
//! checkpoints hold one tensor per section, named after the section.
//!
//! The shaders read the same layout from `shaders/param_layout.wgsl`, which
//! [`wgsl_layout`] writes: `TADGS_BLESS=1 cargo test --release --test gpu_layout` regenerates
//! it, and that test fails while the file and the declaration disagree.

use crate::components::{GaussianParams, GroupOf, PARAM_GROUPS, Param, each_param};
use crate::model::deform::FOURIER_TERMS;
use crate::model::sh::SH_COEFFS;

/// Number of sections: one more than the highest section of any group.
pub const SECTIONS: usize = {
    let mut count = 0;
    let mut i = 0;
    while i < PARAM_GROUPS.len() {
        if PARAM_GROUPS[i].section + 1 > count {
            count = PARAM_GROUPS[i].section + 1;
        }
        i += 1;
    }
    count
};

/// `f32` values per Gaussian in each section: the widths of its groups, added.
pub const WIDTHS: [usize; SECTIONS] = {
    let mut widths = [0; SECTIONS];
    let mut i = 0;
    while i < PARAM_GROUPS.len() {
        widths[PARAM_GROUPS[i].section] += PARAM_GROUPS[i].floats;
        i += 1;
    }
    widths
};

/// `f32` values per Gaussian over every section.
pub const PARAM_FLOATS: usize = {
    let mut sum = 0;
    let mut k = 0;
    while k < SECTIONS {
        sum += WIDTHS[k];
        k += 1;
    }
    sum
};

/// Each section's name: that of its first group.
pub const SECTION_NAMES: [&str; SECTIONS] = {
    let mut names = [""; SECTIONS];
    let mut i = PARAM_GROUPS.len();
    while i > 0 {
        i -= 1;
        names[PARAM_GROUPS[i].section] = PARAM_GROUPS[i].name;
    }
    names
};

// Every section holds at least one group, and groups of one section are declared together
// (so each group's offset in its section is the width of the groups declared before it).
const _: () = {
    let mut k = 0;
    while k < SECTIONS {
        assert!(WIDTHS[k] > 0, "a GPU section without a parameter group");
        k += 1;
    }
    let mut i = 1;
    while i < PARAM_GROUPS.len() {
        assert!(
            PARAM_GROUPS[i].section == PARAM_GROUPS[i - 1].section
                || PARAM_GROUPS[i].section == PARAM_GROUPS[i - 1].section + 1,
            "parameter groups must be declared in section order"
        );
        i += 1;
    }
};

/// Offset of group `index` (of [`PARAM_GROUPS`]) within each Gaussian's values of its section.
pub const fn offset_in_section(index: usize) -> usize {
    let section = PARAM_GROUPS[index].section;
    let mut offset = 0;
    let mut i = 0;
    while i < index {
        if PARAM_GROUPS[i].section == section {
            offset += PARAM_GROUPS[i].floats;
        }
        i += 1;
    }
    offset
}

/// Where group `P`'s values of Gaussian `slot` lie in a buffer of the resident layout holding
/// `count` Gaussians.
pub fn group_range<P: Param>(count: usize, slot: usize) -> std::ops::Range<usize> {
    let section = PARAM_GROUPS[P::INDEX].section;
    let prefix: usize = WIDTHS[..section].iter().sum();
    let start = prefix * count + slot * WIDTHS[section] + offset_in_section(P::INDEX);
    start..start + P::FLOATS
}

/// Every group of `gaussians` in the layout, one array per section: section k holds
/// [`WIDTHS`]`[k]` values per Gaussian, Gaussian-major.
pub fn sections_of(gaussians: &[GaussianParams]) -> [Vec<f32>; SECTIONS] {
    let mut sections: [Vec<f32>; SECTIONS] = Default::default();
    for (section, width) in sections.iter_mut().zip(WIDTHS) {
        section.resize(width * gaussians.len(), 0.0);
    }
    macro_rules! put_every_group {
        ($($group:ty,)*) => {
            $(put_group::<$group>(gaussians, &mut sections);)*
        };
    }
    each_param!(put_every_group);
    sections
}

/// The Gaussians held by `sections` (as [`sections_of`] lays them out).
///
/// # Panics
/// Unless every section holds the same number of Gaussians.
pub fn gaussians_of(sections: &[Vec<f32>; SECTIONS]) -> Vec<GaussianParams> {
    let count = sections[0].len() / WIDTHS[0];
    for (section, width) in sections.iter().zip(WIDTHS) {
        assert_eq!(section.len(), count * width, "sections of one population");
    }
    let mut gaussians = vec![GaussianParams::default(); count];
    macro_rules! get_every_group {
        ($($group:ty,)*) => {
            $(get_group::<$group>(sections, &mut gaussians);)*
        };
    }
    each_param!(get_every_group);
    gaussians
}

/// Where group `P` of Gaussian `i` lies in its section's array.
fn in_section<P: Param>(i: usize) -> (usize, std::ops::Range<usize>) {
    let section = PARAM_GROUPS[P::INDEX].section;
    let start = i * WIDTHS[section] + offset_in_section(P::INDEX);
    (section, start..start + P::FLOATS)
}

/// Copies group `P` of every Gaussian into its place in the section arrays.
fn put_group<P: Param>(gaussians: &[GaussianParams], sections: &mut [Vec<f32>; SECTIONS])
where
    GaussianParams: GroupOf<P>,
{
    for (i, gaussian) in gaussians.iter().enumerate() {
        let (section, range) = in_section::<P>(i);
        sections[section][range].copy_from_slice(GroupOf::<P>::group(gaussian).values());
    }
}

/// Copies group `P` of every Gaussian out of its place in the section arrays.
fn get_group<P: Param>(sections: &[Vec<f32>; SECTIONS], gaussians: &mut [GaussianParams])
where
    GaussianParams: GroupOf<P>,
{
    for (i, gaussian) in gaussians.iter_mut().enumerate() {
        let (section, range) = in_section::<P>(i);
        GroupOf::<P>::group_mut(gaussian)
            .values_mut()
            .copy_from_slice(&sections[section][range]);
    }
}

/// The WGSL constants of the layout (`shaders/param_layout.wgsl`), as the declaration gives
/// them: for section S, `WIDTH_S` values per Gaussian starting at `PREFIX_S`·N; for group G,
/// `OFFSET_G` within its section.
pub fn wgsl_layout() -> String {
    let mut out = String::from(
        "// Generated from the parameter declaration (`param_groups!` in src/components.rs) by\n\
         // src/layout.rs; do not edit. Regenerate with\n\
         //   TADGS_BLESS=1 cargo test --release --test gpu_layout\n\n",
    );
    let constant = |out: &mut String, name: &str, value: usize| {
        out.push_str(&format!("const {name}: u32 = {value}u;\n"));
    };
    constant(&mut out, "FOURIER_TERMS", FOURIER_TERMS);
    constant(&mut out, "SH_COEFFS", SH_COEFFS);
    constant(&mut out, "PARAM_FLOATS", PARAM_FLOATS);
    let mut prefix = 0;
    for (name, width) in SECTION_NAMES.iter().zip(WIDTHS) {
        let name = name.to_uppercase();
        constant(&mut out, &format!("WIDTH_{name}"), width);
        constant(&mut out, &format!("PREFIX_{name}"), prefix);
        prefix += width;
    }
    for (index, group) in PARAM_GROUPS.iter().enumerate() {
        let name = group.name.to_uppercase();
        constant(
            &mut out,
            &format!("OFFSET_{name}"),
            offset_in_section(index),
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::components::{Color, ColorRest, Position, Scale, ShCoefficients};

    /// The derived layout is the one the kernels were written for: seven sections, the SH
    /// bands together (DC first), 97 values per Gaussian.
    #[test]
    fn the_sections_follow_the_declaration() {
        assert_eq!(SECTIONS, 7);
        assert_eq!(PARAM_FLOATS, 97);
        assert_eq!(WIDTHS[6], size_of::<ShCoefficients>() / 4);
        assert_eq!(SECTION_NAMES[0], Position::NAME);
        assert_eq!(SECTION_NAMES[6], Color::NAME);
        assert_eq!(offset_in_section(ColorRest::INDEX), 3);
        // Gaussian 2 of 10: the colour section starts after 49 values per Gaussian.
        assert_eq!(
            group_range::<ColorRest>(10, 2),
            490 + 2 * 48 + 3..490 + 2 * 48 + 48
        );
        assert_eq!(group_range::<Scale>(10, 9), 430 + 9 * 6..430 + 10 * 6);
    }
}
