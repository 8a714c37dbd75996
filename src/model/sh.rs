//! View-dependent colour from real spherical harmonics (degree 0–3, 3DGS basis and signs).

use glam::Vec3;

/// Number of SH coefficients per colour channel at degree 3.
pub const SH_COEFFS: usize = 16;

/// Degree-0 constant 1/(2√π).
pub const C0: f32 = 0.282_094_8;
/// Degree-1 constant √3/(2√π).
pub const C1: f32 = 0.488_602_52;
/// Degree-2 constants.
pub const C2: [f32; 5] = [
    1.092_548_5,
    -1.092_548_5,
    0.315_391_57,
    -1.092_548_5,
    0.546_274_24,
];
/// Degree-3 constants.
pub const C3: [f32; 7] = [
    -0.590_043_6,
    2.890_611_4,
    -0.457_045_8,
    0.373_176_34,
    -0.457_045_8,
    1.445_305_7,
    -0.590_043_6,
];

/// Number of coefficients used at `degree` (clamped to 3): (degree + 1)².
#[inline]
pub fn coeff_count(degree: u32) -> usize {
    let d = degree.min(3) as usize + 1;
    d * d
}

/// The SH basis at the unit direction `n`, for the first `count` coefficients (rest zero).
#[inline]
fn basis(count: usize, n: Vec3) -> [f32; SH_COEFFS] {
    let (x, y, z) = (n.x, n.y, n.z);
    let mut b = [0.0; SH_COEFFS];
    b[0] = C0;
    if count > 1 {
        b[1] = -C1 * y;
        b[2] = C1 * z;
        b[3] = -C1 * x;
    }
    if count > 4 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        b[4] = C2[0] * x * y;
        b[5] = C2[1] * y * z;
        b[6] = C2[2] * (2.0 * zz - xx - yy);
        b[7] = C2[3] * x * z;
        b[8] = C2[4] * (xx - yy);
        if count > 9 {
            b[9] = C3[0] * y * (3.0 * xx - yy);
            b[10] = C3[1] * x * y * z;
            b[11] = C3[2] * y * (4.0 * zz - xx - yy);
            b[12] = C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            b[13] = C3[4] * x * (4.0 * zz - xx - yy);
            b[14] = C3[5] * z * (xx - yy);
            b[15] = C3[6] * x * (xx - 3.0 * yy);
        }
    }
    b
}

/// Σ_k d_basis[k]·∇b_k(n): the gradient with respect to the unit direction (treating x, y, z
/// as independent) given dL/d b_k, for the first `count` coefficients.
#[inline]
fn basis_backward(count: usize, n: Vec3, db: &[f32; SH_COEFFS]) -> Vec3 {
    let (x, y, z) = (n.x, n.y, n.z);
    let mut g = Vec3::ZERO;
    if count > 1 {
        g += Vec3::new(-C1 * db[3], -C1 * db[1], C1 * db[2]);
    }
    if count > 4 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        g += Vec3::new(y, x, 0.0) * (C2[0] * db[4]);
        g += Vec3::new(0.0, z, y) * (C2[1] * db[5]);
        g += Vec3::new(-2.0 * x, -2.0 * y, 4.0 * z) * (C2[2] * db[6]);
        g += Vec3::new(z, 0.0, x) * (C2[3] * db[7]);
        g += Vec3::new(2.0 * x, -2.0 * y, 0.0) * (C2[4] * db[8]);
        if count > 9 {
            g += Vec3::new(6.0 * x * y, 3.0 * (xx - yy), 0.0) * (C3[0] * db[9]);
            g += Vec3::new(y * z, x * z, x * y) * (C3[1] * db[10]);
            g += Vec3::new(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z) * (C3[2] * db[11]);
            g += Vec3::new(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy)
                * (C3[3] * db[12]);
            g += Vec3::new(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z) * (C3[4] * db[13]);
            g += Vec3::new(2.0 * x * z, -2.0 * y * z, xx - yy) * (C3[5] * db[14]);
            g += Vec3::new(3.0 * (xx - yy), -6.0 * x * y, 0.0) * (C3[6] * db[15]);
        }
    }
    g
}

/// Unit direction and 1/length; a zero direction maps to +z (only the DC term matters then).
#[inline]
fn unit(dir: Vec3) -> (Vec3, f32) {
    let len2 = dir.length_squared();
    if len2 > f32::MIN_POSITIVE {
        let inv = len2.sqrt().recip();
        (dir * inv, inv)
    } else {
        (Vec3::Z, 0.0)
    }
}

/// Colour before the clamp: Σ_k b_k(n)·coeffs[k] + 0.5.
#[inline]
fn raw_rgb(count: usize, coeffs: &[[f32; 3]; SH_COEFFS], b: &[f32; SH_COEFFS]) -> [f32; 3] {
    let mut rgb = [0.5; 3];
    for k in 0..count {
        for c in 0..3 {
            rgb[c] += b[k] * coeffs[k][c];
        }
    }
    rgb
}

/// Colour seen along `dir` (the unnormalised direction μ(t) − camera centre, normalised
/// here): rgb = Σ basis·coeff + 0.5 over the first (degree + 1)² coefficients, clamped ≥ 0.
#[inline]
pub fn sh_to_rgb(degree: u32, coeffs: &[[f32; 3]; SH_COEFFS], dir: Vec3) -> [f32; 3] {
    let count = coeff_count(degree);
    let b = basis(count, unit(dir).0);
    raw_rgb(count, coeffs, &b).map(|v| v.max(0.0))
}

/// Backward of [`sh_to_rgb`]: (dL/d coeffs, dL/d dir) given `d_rgb`. Clamped channels
/// (raw value < 0) pass no gradient; coefficients above the degree get zero.
#[inline]
pub fn sh_to_rgb_backward(
    degree: u32,
    coeffs: &[[f32; 3]; SH_COEFFS],
    dir: Vec3,
    d_rgb: [f32; 3],
) -> ([[f32; 3]; SH_COEFFS], Vec3) {
    let count = coeff_count(degree);
    let (n, inv_len) = unit(dir);
    let b = basis(count, n);
    let raw = raw_rgb(count, coeffs, &b);
    let g: [f32; 3] = std::array::from_fn(|c| if raw[c] < 0.0 { 0.0 } else { d_rgb[c] });
    let mut d_coeffs = [[0.0; 3]; SH_COEFFS];
    let mut d_basis = [0.0; SH_COEFFS];
    for k in 0..count {
        d_coeffs[k] = g.map(|gc| gc * b[k]);
        d_basis[k] = g[0] * coeffs[k][0] + g[1] * coeffs[k][1] + g[2] * coeffs[k][2];
    }
    let d_n = basis_backward(count, n, &d_basis);
    // d(v/|v|) = (I − n nᵀ) dv / |v|.
    let d_dir = (d_n - n * n.dot(d_n)) * inv_len;
    (d_coeffs, d_dir)
}

/// DC coefficient that reproduces colour `rgb` in every direction: (rgb − 0.5)/C0.
#[inline]
pub fn rgb_to_sh_dc(rgb: f32) -> f32 {
    (rgb - 0.5) / C0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::fd::{Fd, assert_grad};
    use glam::DVec3;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_coeffs(rng: &mut ChaCha8Rng) -> [[f32; 3]; SH_COEFFS] {
        let mut coeffs: [[f32; 3]; SH_COEFFS] =
            std::array::from_fn(|_| std::array::from_fn(|_| rng.random_range(-0.3..0.3)));
        // Bright DC so no channel is near the clamp.
        coeffs[0] = std::array::from_fn(|_| rng.random_range(2.0..4.0));
        coeffs
    }

    #[test]
    fn dc_round_trip_and_degree_zero() {
        let mut coeffs = [[0.0; 3]; SH_COEFFS];
        coeffs[0] = [rgb_to_sh_dc(0.2), rgb_to_sh_dc(0.5), rgb_to_sh_dc(0.9)];
        // Higher coefficients are ignored at degree 0.
        coeffs[5] = [1.0; 3];
        let rgb = sh_to_rgb(0, &coeffs, Vec3::new(0.3, -2.0, 1.0));
        for (v, e) in rgb.iter().zip([0.2, 0.5, 0.9]) {
            assert!((v - e).abs() < 1e-6);
        }
        assert!(
            sh_to_rgb(0, &[[-5.0; 3]; SH_COEFFS], Vec3::X)
                .iter()
                .all(|&v| v == 0.0)
        );
    }

    #[test]
    fn basis_is_orthonormal() {
        // Monte-Carlo check of ∫ b_i b_j dΩ = δ_ij over a Fibonacci sphere.
        let n = 20_000;
        let mut gram = [[0.0f64; SH_COEFFS]; SH_COEFFS];
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            let phi = i as f32 * 2.399_963;
            let b = basis(SH_COEFFS, Vec3::new(r * phi.cos(), r * phi.sin(), z));
            for a in 0..SH_COEFFS {
                for c in 0..SH_COEFFS {
                    gram[a][c] += (b[a] * b[c]) as f64;
                }
            }
        }
        let w = 4.0 * std::f64::consts::PI / n as f64;
        for a in 0..SH_COEFFS {
            for c in 0..SH_COEFFS {
                let expect = if a == c { 1.0 } else { 0.0 };
                assert!(
                    (gram[a][c] * w - expect).abs() < 1e-3,
                    "({a}, {c}): {}",
                    gram[a][c] * w
                );
            }
        }
    }

    /// The basis in f64 for finite differences free of f32 round-off (rgb sums 16 terms next
    /// to the 0.5 offset and the DC term, so f32 differences of small gradients are noisy).
    fn basis_f64(count: usize, d: DVec3) -> [f64; SH_COEFFS] {
        let n = d.normalize();
        let (x, y, z) = (n.x, n.y, n.z);
        let (xx, yy, zz) = (x * x, y * y, z * z);
        let c2 = C2.map(f64::from);
        let c3 = C3.map(f64::from);
        let c1 = C1 as f64;
        let all = [
            C0 as f64,
            -c1 * y,
            c1 * z,
            -c1 * x,
            c2[0] * x * y,
            c2[1] * y * z,
            c2[2] * (2.0 * zz - xx - yy),
            c2[3] * x * z,
            c2[4] * (xx - yy),
            c3[0] * y * (3.0 * xx - yy),
            c3[1] * x * y * z,
            c3[2] * y * (4.0 * zz - xx - yy),
            c3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            c3[4] * x * (4.0 * zz - xx - yy),
            c3[5] * z * (xx - yy),
            c3[6] * x * (xx - 3.0 * yy),
        ];
        std::array::from_fn(|k| if k < count { all[k] } else { 0.0 })
    }

    /// Σ_c d_rgb[c]·rgb[c] in f64 (no clamp: the tests keep every channel positive).
    fn loss_f64(degree: u32, coeffs: &[[f64; 3]; SH_COEFFS], dir: DVec3, d_rgb: [f64; 3]) -> f64 {
        let b = basis_f64(coeff_count(degree), dir);
        (0..SH_COEFFS)
            .map(|k| b[k] * (0..3).map(|c| coeffs[k][c] * d_rgb[c]).sum::<f64>())
            .sum::<f64>()
            + 0.5 * d_rgb.iter().sum::<f64>()
    }

    /// Fourth-order central difference in f64.
    fn central_f64(f: impl Fn(f64) -> f64, x: f64, h: f64) -> f64 {
        (8.0 * (f(x + h) - f(x - h)) - (f(x + 2.0 * h) - f(x - 2.0 * h))) / (12.0 * h)
    }

    #[test]
    fn forward_matches_f64() {
        let mut rng = ChaCha8Rng::seed_from_u64(10);
        for degree in 0..4 {
            let coeffs = random_coeffs(&mut rng);
            let dir = Vec3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
            );
            let rgb = sh_to_rgb(degree, &coeffs, dir);
            let c64 = coeffs.map(|c| c.map(f64::from));
            for c in 0..3 {
                let mut one_hot = [0.0; 3];
                one_hot[c] = 1.0;
                assert!(
                    (rgb[c] as f64 - loss_f64(degree, &c64, dir.as_dvec3(), one_hot)).abs() < 1e-5
                );
            }
        }
    }

    #[test]
    fn backward_matches_fd() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for trial in 0..24 {
            let degree = trial % 4;
            let coeffs = random_coeffs(&mut rng);
            let dir = Vec3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
            );
            let (c64, dir64) = (coeffs.map(|c| c.map(f64::from)), dir.as_dvec3());
            // One channel at a time (one-hot upstream gradient), then a random mix.
            let random: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            for d_rgb in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], random] {
                let (g_coeffs, g_dir) = sh_to_rgb_backward(degree, &coeffs, dir, d_rgb);
                let d64 = d_rgb.map(f64::from);
                let mut fd_coeffs = [[0.0f64; 3]; SH_COEFFS];
                for k in 0..SH_COEFFS {
                    for c in 0..3 {
                        let f = |v| {
                            let mut m = c64;
                            m[k][c] = v;
                            loss_f64(degree, &m, dir64, d64)
                        };
                        fd_coeffs[k][c] = central_f64(f, c64[k][c], 1e-3);
                    }
                }
                let fd_dir: [f64; 3] = std::array::from_fn(|a| {
                    let f = |v| {
                        let mut d = dir64;
                        d[a] = v;
                        loss_f64(degree, &c64, d, d64)
                    };
                    central_f64(f, dir64[a], 1e-4 * dir64.length())
                });
                // f64 differences are accurate to ~1e-9 relative; the floor covers the f32
                // analytic gradient, whose direction part sums up to 16 basis-gradient terms
                // that can be much larger than a nearly cancelling result: 1e-5 of the largest
                // component (~100 f32 roundings of the largest term).
                let largest = fd_coeffs
                    .iter()
                    .flatten()
                    .chain(&fd_dir)
                    .fold(0.0f64, |m, v| m.max(v.abs()));
                let floor = (1e-5 * largest) as f32;
                for k in 0..SH_COEFFS {
                    for c in 0..3 {
                        assert_grad(
                            "coeff",
                            g_coeffs[k][c],
                            Fd {
                                value: fd_coeffs[k][c] as f32,
                                noise: floor,
                            },
                        );
                    }
                }
                for a in 0..3 {
                    assert_grad(
                        "dir",
                        g_dir[a],
                        Fd {
                            value: fd_dir[a] as f32,
                            noise: floor,
                        },
                    );
                }
            }
        }
    }

    #[test]
    fn clamped_channel_has_no_gradient() {
        let mut coeffs = [[0.0; 3]; SH_COEFFS];
        coeffs[0] = [rgb_to_sh_dc(-0.5), rgb_to_sh_dc(0.5), rgb_to_sh_dc(0.5)];
        coeffs[1] = [0.3; 3];
        let (g, d) = sh_to_rgb_backward(1, &coeffs, Vec3::new(0.0, 1.0, 1.0), [1.0, 0.0, 0.0]);
        assert!(g.iter().all(|c| c[0] == 0.0));
        assert_eq!(d, Vec3::ZERO);
        let (g, _) = sh_to_rgb_backward(1, &coeffs, Vec3::new(0.0, 1.0, 1.0), [0.0, 1.0, 0.0]);
        assert_eq!(g[0][1], C0);
    }
}
