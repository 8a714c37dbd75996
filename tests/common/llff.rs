//! Writers of N3DV's LLFF files (`poses_bounds.npy`) for the tests that build N3DV scenes.
#![allow(dead_code)]

use std::path::Path;

/// Writes a version-1.0 `.npy` file with the given dtype descriptor, shape and raw data.
pub fn write_npy(path: &Path, descr: &str, shape: &[usize], data: &[u8]) {
    let shape_text = match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
    // Magic (6) + version (2) + length (2) + header, padded with spaces to a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    bytes.extend_from_slice(data);
    std::fs::write(path, bytes).unwrap();
}

pub fn write_poses(path: &Path, rows: &[[f64; 17]]) {
    let data: Vec<u8> = rows
        .iter()
        .flatten()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    write_npy(path, "<f8", &[rows.len(), 17], &data);
}

/// One `poses_bounds.npy` row from LLFF camera axes (down, right, backwards in world
/// coordinates), the camera centre and `hwf`.
pub fn llff_row(
    down: [f64; 3],
    right: [f64; 3],
    backwards: [f64; 3],
    centre: [f64; 3],
    hwf: [f64; 3],
) -> [f64; 17] {
    let columns = [down, right, backwards, centre, hwf];
    let mut row = [0.0; 17];
    for r in 0..3 {
        for (c, column) in columns.iter().enumerate() {
            row[r * 5 + c] = column[r];
        }
    }
    row[15] = 0.5; // near
    row[16] = 100.0; // far
    row
}
