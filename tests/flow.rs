//! Dense optical flow and dynamic masks (`tadgs::metrics::flow`).

mod common;

use std::time::Instant;
use tadgs::io::image::Image;
use tadgs::metrics::flow::{
    DEFAULT_FLOW_THRESHOLD, MASK_FRAME_GAP, dense_flow, dynamic_mask, mask_from_image,
    mask_to_image,
};

/// A smooth random texture: a sum of sinusoids with pseudo-random directions, wavelengths
/// (12–40 px) and phases, evaluated analytically so it can be translated exactly.
struct Texture {
    waves: Vec<(f32, f32, f32, f32)>, // (kx, ky, phase, amplitude)
}

impl Texture {
    fn new(seed: u64, count: usize) -> Self {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(1);
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f32 / (1u64 << 53) as f32
        };
        let waves = (0..count)
            .map(|_| {
                let angle = next() * std::f32::consts::TAU;
                let wavelength = 12.0 + 28.0 * next();
                let k = std::f32::consts::TAU / wavelength;
                (
                    k * angle.cos(),
                    k * angle.sin(),
                    next() * std::f32::consts::TAU,
                    0.5 + next(),
                )
            })
            .collect::<Vec<_>>();
        Self { waves }
    }

    /// Intensity in [0.1, 0.9] at a continuous position.
    fn at(&self, x: f32, y: f32) -> f32 {
        let total: f32 = self.waves.iter().map(|w| w.3).sum();
        let v: f32 = self
            .waves
            .iter()
            .map(|&(kx, ky, ph, amp)| amp * (kx * x + ky * y + ph).sin())
            .sum();
        0.5 + 0.4 * v / total
    }

    /// RGB image of `width × height` with pixel (x, y) showing the texture at (x − dx, y − dy)
    /// (so content moves by +(dx, dy)).
    fn image(&self, width: usize, height: usize, dx: f32, dy: f32) -> Image {
        let data = (0..width * height)
            .map(|i| {
                let (x, y) = ((i % width) as f32, (i / width) as f32);
                let v = self.at(x - dx, y - dy);
                [v, 0.8 * v + 0.1, 1.0 - v]
            })
            .collect();
        Image {
            width,
            height,
            data,
        }
    }
}

/// Mean, 99th-percentile and maximum endpoint error over the pixels at least `margin` from
/// the border.
fn interior_error(a: &Image, b: &Image, truth: [f32; 2], margin: usize) -> (f32, f32, f32) {
    let flow = dense_flow(a, b);
    assert_eq!((flow.width, flow.height), (a.width, a.height));
    let mut errors = Vec::new();
    for y in margin..a.height - margin {
        for x in margin..a.width - margin {
            let f = flow.data[y * a.width + x];
            errors.push(((f[0] - truth[0]).powi(2) + (f[1] - truth[1]).powi(2)).sqrt());
        }
    }
    errors.sort_by(f32::total_cmp);
    let mean = errors.iter().sum::<f32>() / errors.len() as f32;
    let p99 = errors[errors.len() * 99 / 100];
    (mean, p99, *errors.last().unwrap())
}

#[test]
fn translation_is_recovered() {
    let tex = Texture::new(7, 12);
    let (w, h) = (192, 128);
    let a = tex.image(w, h, 0.0, 0.0);
    for truth in [[3.0f32, -2.0], [0.5, 0.25], [-1.25, 0.75], [7.5, 4.0]] {
        let b = tex.image(w, h, truth[0], truth[1]);
        let (mean, p99, max) = interior_error(&a, &b, truth, 16);
        println!("truth {truth:?}: endpoint error mean {mean:.4}, p99 {p99:.4}, max {max:.4} px");
        assert!(mean < 0.1, "mean error {mean} px for {truth:?}");
        assert!(p99 < 0.3, "99th-percentile error {p99} px for {truth:?}");
        assert!(max < 0.5, "max error {max} px for {truth:?}");
    }
}

#[test]
fn identical_images_give_zero_flow() {
    let a = Texture::new(3, 10).image(100, 70, 0.0, 0.0);
    let flow = dense_flow(&a, &a);
    assert!(flow.magnitude().iter().all(|&m| m < 1e-4));
    assert!(
        dynamic_mask(&a, &a, DEFAULT_FLOW_THRESHOLD)
            .iter()
            .all(|&m| !m)
    );
    let flat = Image::filled(33, 21, [0.4, 0.5, 0.6]);
    assert!(
        dense_flow(&flat, &flat)
            .magnitude()
            .iter()
            .all(|&m| m == 0.0)
    );
}

#[test]
#[should_panic(expected = "image sizes differ")]
fn size_mismatch_panics() {
    let _ = dense_flow(
        &Image::filled(10, 10, [0.0; 3]),
        &Image::filled(11, 10, [0.0; 3]),
    );
}

#[test]
fn magnitude_is_euclidean() {
    let flow = tadgs::metrics::flow::Flow {
        width: 2,
        height: 1,
        data: vec![[3.0, -4.0], [0.0, 0.5]],
    };
    assert_eq!(flow.magnitude(), vec![5.0, 0.5]);
}

/// A textured square moving over a static textured background.
#[test]
fn moving_square_mask() {
    let (w, h) = (200, 150);
    let background = Texture::new(11, 12);
    let square = Texture::new(29, 12);
    let side = 40usize;
    let (p0, p1) = ((60usize, 50usize), (68usize, 45usize)); // moves by (8, −5) in 5 frames
    let render = |p: (usize, usize)| {
        let mut img = background.image(w, h, 0.0, 0.0);
        for y in p.1..p.1 + side {
            for x in p.0..p.0 + side {
                let v = square.at((x - p.0) as f32, (y - p.1) as f32);
                img.data[y * w + x] = [1.0 - v, v, 0.5 * v + 0.25];
            }
        }
        img
    };
    let (earlier, current) = (render(p0), render(p1));
    let mask = dynamic_mask(&earlier, &current, DEFAULT_FLOW_THRESHOLD);
    assert_eq!(mask.len(), w * h);

    let inside = |p: (usize, usize), x: usize, y: usize| {
        x >= p.0 && x < p.0 + side && y >= p.1 && y < p.1 + side
    };
    let dist = |p: (usize, usize), x: usize, y: usize| {
        let dx = (p.0 as isize - x as isize).max(x as isize - (p.0 + side - 1) as isize);
        let dy = (p.1 as isize - y as isize).max(y as isize - (p.1 + side - 1) as isize);
        dx.max(dy).max(0) as usize
    };
    let (mut now, mut left, mut far) = ([0usize; 2], [0usize; 2], [0usize; 2]);
    for y in 0..h {
        for x in 0..w {
            let m = mask[y * w + x] as usize;
            let counter = if inside(p1, x, y) {
                &mut now
            } else if inside(p0, x, y) {
                &mut left
            } else if dist(p0, x, y) > 10 && dist(p1, x, y) > 10 {
                &mut far
            } else {
                continue;
            };
            counter[0] += m;
            counter[1] += 1;
        }
    }
    let frac = |c: [usize; 2]| c[0] as f64 / c[1] as f64;
    println!(
        "square now {:.4}, region left {:.4}, far background {:.4}",
        frac(now),
        frac(left),
        frac(far)
    );
    assert!(frac(now) >= 0.95, "square covered {:.4}", frac(now));
    assert!(frac(left) >= 0.95, "region left covered {:.4}", frac(left));
    assert!(frac(far) < 0.02, "far background flagged {:.4}", frac(far));
}

#[test]
fn mask_png_round_trip() {
    let (w, h) = (37, 23);
    let mask: Vec<bool> = (0..w * h).map(|i| (i * 7 + i / 5) % 3 == 0).collect();
    let img = mask_to_image(&mask, w, h);
    assert_eq!((img.width, img.height), (w, h));
    assert_eq!(mask_from_image(&img), mask);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mask.png");
    img.save_png(&path).unwrap();
    let loaded = Image::load(&path).unwrap();
    assert_eq!(mask_from_image(&loaded), mask);
}

/// Real video: CMU Panoptic basketball, test camera 0, frame 5 vs frame 0.
#[test]
fn panoptic_mask_is_plausible() {
    let Some(data) = common::data_dir() else {
        return;
    };
    let ims = data.join("panoptic_basketball/ims/0");
    let load = |frame: usize| {
        let path = ims.join(format!("{frame:06}.jpg"));
        Image::load(&path).unwrap_or_else(|e| panic!("{e}"))
    };
    let (earlier, current) = (load(0), load(MASK_FRAME_GAP));
    let start = Instant::now();
    let flow = dense_flow(&earlier, &current);
    let elapsed = start.elapsed();
    println!(
        "dense_flow {}x{}: {:.1} ms",
        flow.width,
        flow.height,
        elapsed.as_secs_f64() * 1e3
    );
    let mask = dynamic_mask(&earlier, &current, DEFAULT_FLOW_THRESHOLD);
    let coverage = mask.iter().filter(|&&m| m).count() as f64 / mask.len() as f64;
    println!("panoptic cam 0 frame 5 dynamic fraction {coverage:.4}");
    assert!(coverage > 0.0, "mask is empty");
    assert!(coverage < 0.30, "mask covers {coverage:.4} of the image");
}

/// Real video with ground-truth foreground: training camera 1, frame 5 vs frame 0. Most
/// dynamic pixels must lie on or near the players (the union of both frames' segmentation,
/// dilated by a few pixels), and the moving players must be found.
#[test]
fn panoptic_mask_matches_segmentation() {
    let Some(data) = common::data_dir() else {
        return;
    };
    let root = data.join("panoptic_basketball");
    let load = |dir: &str, ext: &str, frame: usize| {
        let path = root.join(format!("{dir}/1/{frame:06}.{ext}"));
        Image::load(&path).unwrap_or_else(|e| panic!("{e}"))
    };
    let (earlier, current) = (load("ims", "jpg", 0), load("ims", "jpg", MASK_FRAME_GAP));
    let (s0, s1) = (load("seg", "png", 0), load("seg", "png", MASK_FRAME_GAP));
    let (w, h) = (current.width, current.height);
    let mask = dynamic_mask(&earlier, &current, DEFAULT_FLOW_THRESHOLD);
    let fg: Vec<bool> = s0
        .data
        .iter()
        .zip(&s1.data)
        .map(|(a, b)| a[0] > 0.5 || b[0] > 0.5)
        .collect();
    let radius = 8isize;
    let near_fg = |x: usize, y: usize| {
        (-radius..=radius).any(|dy| {
            (-radius..=radius).any(|dx| {
                let (xx, yy) = (x as isize + dx, y as isize + dy);
                xx >= 0
                    && yy >= 0
                    && (xx as usize) < w
                    && (yy as usize) < h
                    && fg[yy as usize * w + xx as usize]
            })
        })
    };
    let (mut flagged, mut flagged_near) = (0usize, 0usize);
    for y in 0..h {
        for x in 0..w {
            if mask[y * w + x] {
                flagged += 1;
                flagged_near += near_fg(x, y) as usize;
            }
        }
    }
    let fg_count = fg.iter().filter(|&&f| f).count();
    let fg_flagged = fg.iter().zip(&mask).filter(|&(&f, &m)| f && m).count();
    let precision = flagged_near as f64 / flagged.max(1) as f64;
    println!(
        "cam 1: flagged {flagged} px ({:.4}), {precision:.4} near foreground; foreground {fg_count} px, {:.4} flagged",
        flagged as f64 / (w * h) as f64,
        fg_flagged as f64 / fg_count.max(1) as f64
    );
    assert!(flagged > 0, "mask is empty");
    assert!(
        precision > 0.8,
        "only {precision:.4} of the mask is near the players"
    );
}
