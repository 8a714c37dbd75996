//! Lens undistortion for COLMAP's perspective camera models, done once when images are read.
//!
//! COLMAP projects a point with normalised camera coordinates (u, v) = (x/z, y/z) to the pixel
//! (fx·(u + du) + cx, fy·(v + dv) + cy), where (du, dv) comes from the model's distortion
//! coefficients (`src/colmap/sensor/models.h`; pixel centres at +0.5, as in [`Camera`]).
//! tadgs renders pinhole cameras only, so a distorted image is resampled onto the pinhole
//! camera with the same fx, fy, cx, cy and size: every output pixel centre is normalised,
//! distorted by the forward model, mapped back to a pixel of the source image and sampled
//! bilinearly. Output pixels whose source lies outside the image get the background colour.
//! Fisheye models are not handled here (the COLMAP reader refuses them).

use image::RgbImage;

use super::Camera;

/// The distortion of a COLMAP perspective camera model, in normalised image coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Distortion {
    /// SIMPLE_PINHOLE and PINHOLE: none.
    None,
    /// SIMPLE_RADIAL: radial factor k·r².
    SimpleRadial {
        /// Coefficient of r².
        k: f64,
    },
    /// RADIAL: radial factor k1·r² + k2·r⁴.
    Radial {
        /// Coefficient of r².
        k1: f64,
        /// Coefficient of r⁴.
        k2: f64,
    },
    /// OPENCV: radial k1·r² + k2·r⁴ and tangential p1, p2.
    OpenCv {
        /// Coefficient of r².
        k1: f64,
        /// Coefficient of r⁴.
        k2: f64,
        /// First tangential coefficient.
        p1: f64,
        /// Second tangential coefficient.
        p2: f64,
    },
    /// FULL_OPENCV: rational radial (1 + k1·r² + k2·r⁴ + k3·r⁶) / (1 + k4·r² + k5·r⁴ + k6·r⁶)
    /// and tangential p1, p2.
    FullOpenCv {
        /// k1 … k6 of the rational radial factor.
        k: [f64; 6],
        /// First tangential coefficient.
        p1: f64,
        /// Second tangential coefficient.
        p2: f64,
    },
}

impl Distortion {
    /// The distortion of COLMAP model `model` from its parameters after the focal lengths and
    /// principal point (in COLMAP's order); `None` for a model without distortion or an
    /// unknown one.
    pub fn from_colmap(model: &str, extra: &[f64]) -> Self {
        match (model, extra) {
            ("SIMPLE_RADIAL", &[k]) => Self::SimpleRadial { k },
            ("RADIAL", &[k1, k2]) => Self::Radial { k1, k2 },
            ("OPENCV", &[k1, k2, p1, p2]) => Self::OpenCv { k1, k2, p1, p2 },
            ("FULL_OPENCV", &[k1, k2, p1, p2, k3, k4, k5, k6]) => Self::FullOpenCv {
                k: [k1, k2, k3, k4, k5, k6],
                p1,
                p2,
            },
            _ => Self::None,
        }
    }

    /// Whether the model leaves every point where it is (no model, or every coefficient 0).
    pub fn is_identity(&self) -> bool {
        match *self {
            Self::None => true,
            Self::SimpleRadial { k } => k == 0.0,
            Self::Radial { k1, k2 } => k1 == 0.0 && k2 == 0.0,
            Self::OpenCv { k1, k2, p1, p2 } => [k1, k2, p1, p2].iter().all(|&c| c == 0.0),
            Self::FullOpenCv { k, p1, p2 } => k.iter().chain(&[p1, p2]).all(|&c| c == 0.0),
        }
    }

    /// The distorted position of the normalised point (u, v): (u + du, v + dv), COLMAP's
    /// forward model.
    pub fn distort(&self, u: f64, v: f64) -> (f64, f64) {
        let r2 = u * u + v * v;
        let tangential = |p1: f64, p2: f64| {
            (
                2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u),
                2.0 * p2 * u * v + p1 * (r2 + 2.0 * v * v),
            )
        };
        let (radial, (tu, tv)) = match *self {
            Self::None => (0.0, (0.0, 0.0)),
            Self::SimpleRadial { k } => (k * r2, (0.0, 0.0)),
            Self::Radial { k1, k2 } => (k1 * r2 + k2 * r2 * r2, (0.0, 0.0)),
            Self::OpenCv { k1, k2, p1, p2 } => (k1 * r2 + k2 * r2 * r2, tangential(p1, p2)),
            Self::FullOpenCv { k, p1, p2 } => {
                let (r4, r6) = (r2 * r2, r2 * r2 * r2);
                let numerator = 1.0 + k[0] * r2 + k[1] * r4 + k[2] * r6;
                let denominator = 1.0 + k[3] * r2 + k[4] * r4 + k[5] * r6;
                (numerator / denominator - 1.0, tangential(p1, p2))
            }
        };
        (u + u * radial + tu, v + v * radial + tv)
    }
}

/// A resampling map from a distorted camera's images to its pinhole camera (same size and
/// intrinsics), computed once per camera and applied to each of its frames.
#[derive(Clone, Debug)]
pub struct Undistortion {
    width: u32,
    height: u32,
    /// For each output pixel (row-major), where to sample the distorted image, in pixel
    /// coordinates with centres at +0.5.
    sources: Vec<[f32; 2]>,
}

impl Undistortion {
    /// The map for `camera`'s size and pinhole intrinsics with lens `distortion`.
    pub fn new(distortion: &Distortion, camera: &Camera) -> Self {
        let [fx, fy, cx, cy] = [camera.fx, camera.fy, camera.cx, camera.cy].map(f64::from);
        let mut sources = Vec::with_capacity(camera.width as usize * camera.height as usize);
        for y in 0..camera.height {
            for x in 0..camera.width {
                let u = (f64::from(x) + 0.5 - cx) / fx;
                let v = (f64::from(y) + 0.5 - cy) / fy;
                let (du, dv) = distortion.distort(u, v);
                sources.push([(fx * du + cx) as f32, (fy * dv + cy) as f32]);
            }
        }
        Self {
            width: camera.width,
            height: camera.height,
            sources,
        }
    }

    /// Where output pixel (x, y) samples the distorted image (pixel centres at +0.5).
    pub fn source(&self, x: u32, y: u32) -> [f32; 2] {
        self.sources[(y * self.width + x) as usize]
    }

    /// The pinhole image of the distorted `image`, which must have the camera's size:
    /// bilinear samples, `background` where the source position is outside the image.
    pub fn apply(&self, image: &RgbImage, background: [u8; 3]) -> RgbImage {
        assert_eq!(
            image.dimensions(),
            (self.width, self.height),
            "undistortion map and image sizes differ"
        );
        let (w, h) = (self.width as f32, self.height as f32);
        let clamp_x = |i: f32| (i.max(0.0) as u32).min(self.width - 1);
        let clamp_y = |i: f32| (i.max(0.0) as u32).min(self.height - 1);
        let mut out = RgbImage::new(self.width, self.height);
        for (pixel, &[sx, sy]) in out.pixels_mut().zip(&self.sources) {
            if !(0.0..=w).contains(&sx) || !(0.0..=h).contains(&sy) {
                pixel.0 = background;
                continue;
            }
            let (px, py) = (sx - 0.5, sy - 0.5);
            let (x0, y0) = (px.floor(), py.floor());
            let (ax, ay) = (px - x0, py - y0);
            let (xa, xb, ya, yb) = (
                clamp_x(x0),
                clamp_x(x0 + 1.0),
                clamp_y(y0),
                clamp_y(y0 + 1.0),
            );
            let at = |x: u32, y: u32, c: usize| f32::from(image.get_pixel(x, y).0[c]);
            for c in 0..3 {
                let top = at(xa, ya, c) * (1.0 - ax) + at(xb, ya, c) * ax;
                let bottom = at(xa, yb, c) * (1.0 - ax) + at(xb, yb, c) * ax;
                pixel.0[c] = (top * (1.0 - ay) + bottom * ay).round().clamp(0.0, 255.0) as u8;
            }
        }
        out
    }
}
