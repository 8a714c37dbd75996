//! The viewer's renderer: a render-only world (time warp, deformation, splatting) holding one
//! model, which draws a camera at a time and encodes the image for the page.
//!
//! It is built exactly as `tadgs render` builds its world (the run's scene settings, the
//! model's SH degree, [`render_schedule`]), so a frame shown by the viewer has the pixels
//! `tadgs render --camera … --time …` writes for the same camera and time.

use std::time::Instant;

use bevy_ecs::prelude::{Entity, With, World};
use serde::{Deserialize, Serialize};

use crate::components::{Deformed, Position};
use crate::data::{Camera, frame_time};
use crate::gpu::GpuError;
use crate::io::camera_path::CameraSpec;
use crate::io::image::Image;
use crate::io::model::Model;
use crate::model::project::drawable;
use crate::resources::{Settings, SplatBuffers, TrainState, ViewSample};
use crate::scene::SceneConfig;
use crate::systems::render_schedule;
use crate::train::insert_render_resources;

/// The largest side of a frame the viewer renders: requests are bounded before anything is
/// allocated, so one malformed message cannot make the server reserve gigabytes.
pub const MAX_VIEW_SIDE: u32 = 4096;
/// The largest frame in pixels (3840 × 2160): a 4K still is the most a browser tab shows.
pub const MAX_VIEW_PIXELS: u64 = 3840 * 2160;

/// How the page wants a frame encoded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ImageFormat {
    /// Lossless: the exact pixels of `tadgs render` (the view at rest).
    #[default]
    Png,
    /// Lossy but smaller and faster to encode (while the view moves or plays).
    Jpeg,
}

/// One frame the page asks for: a camera, a time, an encoding.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameRequest {
    /// The page's number for this request, echoed in the reply (to match replies to
    /// requests and measure latency).
    #[serde(default)]
    pub id: u64,
    /// The camera, in the form of a `tadgs render --camera` file (OpenCV convention).
    pub camera: CameraSpec,
    /// Normalised time in [0, 1]. Give either this or `frame`.
    #[serde(default)]
    pub time: Option<f32>,
    /// A frame of the sequence; its time is `frame / (frames − 1)`, computed as the dataset
    /// and `tadgs render` compute it, so a frame on the slider is exactly that frame's time.
    #[serde(default)]
    pub frame: Option<usize>,
    /// PNG (default) or JPEG.
    #[serde(default)]
    pub format: ImageFormat,
    /// JPEG quality, 1–100 (default 85); ignored for PNG.
    #[serde(default)]
    pub quality: Option<u8>,
}

/// What is wrong with a [`FrameRequest`] (the page shows it; HTTP answers 400).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RequestError {
    /// The camera is unusable (size, intrinsics, not a rigid transform).
    #[error("camera: {0}")]
    Camera(String),
    /// The frame is larger than the viewer renders.
    #[error(
        "a {width}×{height} frame is larger than the viewer renders ({MAX_VIEW_SIDE} pixels a \
         side, {MAX_VIEW_PIXELS} pixels in all)"
    )]
    TooLarge {
        /// Requested width.
        width: u32,
        /// Requested height.
        height: u32,
    },
    /// Neither or both of `time` and `frame` were given, or the value is out of range.
    #[error("{0}")]
    Time(String),
    /// JPEG quality outside 1–100.
    #[error("quality must lie in 1..=100, got {0}")]
    Quality(u8),
}

impl FrameRequest {
    /// The camera and time to render, checked against the model's `frame_count`.
    pub fn resolve(&self, frame_count: usize) -> Result<(Camera, f32), RequestError> {
        let spec = &self.camera;
        if spec.width > MAX_VIEW_SIDE
            || spec.height > MAX_VIEW_SIDE
            || spec.width as u64 * spec.height as u64 > MAX_VIEW_PIXELS
        {
            return Err(RequestError::TooLarge {
                width: spec.width,
                height: spec.height,
            });
        }
        let camera = spec.to_camera().map_err(RequestError::Camera)?;
        let time = match (self.time, self.frame) {
            (Some(time), None) if (0.0..=1.0).contains(&time) => time,
            (Some(time), None) => {
                return Err(RequestError::Time(format!(
                    "time must lie in [0, 1], got {time}"
                )));
            }
            (None, Some(frame)) if frame < frame_count.max(1) => frame_time(frame, frame_count),
            (None, Some(frame)) => {
                return Err(RequestError::Time(format!(
                    "frame {frame} does not exist (the sequence has {frame_count} frames)"
                )));
            }
            _ => {
                return Err(RequestError::Time(
                    "give exactly one of `time` and `frame`".into(),
                ));
            }
        };
        if let Some(quality) = self.quality.filter(|q| !(1..=100).contains(q)) {
            return Err(RequestError::Quality(quality));
        }
        Ok((camera, time))
    }
}

/// A rendered frame and what the page shows beside it.
#[derive(Clone, Debug)]
pub struct RenderedFrame {
    /// The blended image (background included), as `tadgs render` writes it before 8-bit
    /// conversion.
    pub image: Image,
    /// Normalised time it shows.
    pub time: f32,
    /// The sequence frame nearest to `time`.
    pub frame: usize,
    /// Seconds the render schedule took.
    pub render_seconds: f64,
    /// Gaussians in the model.
    pub total: usize,
    /// Gaussians alive at `time` (σ(t) ≥ 1/255, the rule `tadgs export` uses); None when the
    /// backend keeps the deformed Gaussians on the GPU.
    pub alive: Option<usize>,
    /// Gaussians drawn in this view (alive, in front of the camera and on screen); None as for
    /// `alive`.
    pub drawn: Option<usize>,
}

/// A render-only world holding one model.
pub struct Renderer {
    world: World,
    schedule: bevy_ecs::schedule::Schedule,
    frame_count: usize,
    total: usize,
}

impl Renderer {
    /// A world with `scene`'s render settings (background, near plane, deformation, backend)
    /// holding `model`, for a sequence of `frame_count` frames. Fails only when the scene asks
    /// for the GPU backend and no GPU opens, or the model has what it cannot draw.
    pub fn new(scene: &SceneConfig, model: &Model, frame_count: usize) -> Result<Self, GpuError> {
        model.check_backend(scene.train.backend)?;
        let mut world = World::new();
        // The extent only scales learning rates and densification: any value renders the same.
        let placeholder = Camera::look_at(
            glam::Vec3::new(0.0, 0.0, -1.0),
            glam::Vec3::ZERO,
            glam::Vec3::NEG_Y,
            1,
            1,
            1.0,
        );
        insert_render_resources(&mut world, scene, frame_count, 1.0, placeholder)?;
        let mut renderer = Self {
            world,
            schedule: render_schedule(),
            frame_count,
            total: 0,
        };
        renderer.set_model(model);
        Ok(renderer)
    }

    /// Replaces the Gaussians drawn by those of `model` (a newer state of the same run).
    pub fn set_model(&mut self, model: &Model) {
        // Only the Gaussians go: resources are entities too since bevy 0.17.
        let old: Vec<Entity> = self
            .world
            .query_filtered::<Entity, With<Position>>()
            .iter(&self.world)
            .collect();
        for entity in old {
            self.world.despawn(entity);
        }
        self.world.resource_mut::<TrainState>().sh_degree = model.sh_degree;
        model.spawn_into(&mut self.world);
        self.total = model.gaussians.len();
    }

    /// Frames in the sequence the model was trained on.
    pub fn frame_count(&self) -> usize {
        self.frame_count
    }

    /// Gaussians in the model.
    pub fn gaussians(&self) -> usize {
        self.total
    }

    /// Renders `camera` at normalised `time`.
    pub fn render(&mut self, camera: &Camera, time: f32) -> RenderedFrame {
        let start = Instant::now();
        let last = self.frame_count.saturating_sub(1);
        let frame = ((time * last as f32).round() as usize).min(last);
        let background = self.world.resource::<Settings>().train.background;
        *self.world.resource_mut::<ViewSample>() = ViewSample {
            camera: *camera,
            view: None,
            frame,
            time,
            background,
        };
        self.schedule.run(&mut self.world);
        let render_seconds = start.elapsed().as_secs_f64();
        // Counted where the CPU splatting stage drew every Gaussian (the GPU backend leaves
        // the deformed components and the splats unwritten).
        let counted =
            self.world.resource::<SplatBuffers>().splats.len() == self.total && self.total > 0;
        let alive = counted.then(|| {
            self.world
                .query::<&Deformed>()
                .iter(&self.world)
                .filter(|d| drawable(d.opacity))
                .count()
        });
        let buffers = self.world.resource::<SplatBuffers>();
        let drawn = counted.then(|| buffers.splats.iter().filter(|s| s.visible).count());
        RenderedFrame {
            image: buffers.render.image.clone(),
            time,
            frame,
            render_seconds,
            total: self.total,
            alive: alive.or((self.total == 0).then_some(0)),
            drawn: drawn.or((self.total == 0).then_some(0)),
        }
    }
}

/// Encodes `image` as PNG (fast deflate: a 640×360 frame in a few milliseconds, the same
/// pixels as `tadgs render`'s PNG) or JPEG at `quality`.
pub fn encode(image: &Image, format: ImageFormat, quality: u8) -> Vec<u8> {
    use image::ImageEncoder;
    use image::codecs::jpeg::JpegEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let rgb = image.to_rgb8();
    let mut bytes = Vec::new();
    let (width, height) = rgb.dimensions();
    let result = match format {
        ImageFormat::Png => {
            PngEncoder::new_with_quality(&mut bytes, CompressionType::Fast, FilterType::Sub)
                .write_image(&rgb, width, height, image::ExtendedColorType::Rgb8)
        }
        ImageFormat::Jpeg => JpegEncoder::new_with_quality(&mut bytes, quality.clamp(1, 100))
            .write_image(&rgb, width, height, image::ExtendedColorType::Rgb8),
    };
    // Encoding into memory fails only on sizes the request check already refused.
    result.expect("a checked frame encodes");
    bytes
}

/// The camera as the RON text `tadgs render --camera FILE` reads, headed by a comment with the
/// command that renders it at `time`.
pub fn camera_ron(camera: &Camera, time: f32) -> String {
    let spec = CameraSpec::of(camera);
    // Written by hand in the README's layout (one matrix row a line); `{:?}` prints the
    // shortest decimal that reads back as the same f32, so the file renders the same pixels.
    let rows: String = spec
        .world_to_camera
        .iter()
        .map(|row| {
            let values: Vec<String> = row.iter().map(|v| format!("{v:?}")).collect();
            format!("        [{}],\n", values.join(", "))
        })
        .collect();
    format!(
        "// tadgs render INPUT --camera view.ron --time {time:?} --frames 1 -o view.png\n(\n    \
         width: {}, height: {}, fx: {:?}, fy: {:?}, cx: {:?}, cy: {:?},\n    \
         world_to_camera: [\n{rows}    ],\n)\n",
        spec.width, spec.height, spec.fx, spec.fy, spec.cx, spec.cy
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn request(text: &str) -> Result<FrameRequest, serde_json::Error> {
        serde_json::from_str(text)
    }

    fn spec(width: u32, height: u32) -> String {
        let camera = Camera::look_at(
            Vec3::new(0.0, 0.0, -3.0),
            Vec3::ZERO,
            Vec3::NEG_Y,
            width,
            height,
            1.0,
        );
        serde_json::to_string(&CameraSpec::of(&camera)).unwrap()
    }

    /// A frame request names exactly one of time and frame, in range; frame k has the
    /// dataset's time k / (T − 1).
    #[test]
    fn requests_resolve_time_and_frame() {
        let cam = spec(8, 6);
        let at = |extra: &str| {
            request(&format!(r#"{{"camera":{cam}{extra}}}"#))
                .unwrap()
                .resolve(11)
        };
        assert_eq!(at(r#","time":0.5"#).unwrap().1, 0.5);
        assert_eq!(at(r#","frame":3"#).unwrap().1, frame_time(3, 11));
        assert!(matches!(at(r#","frame":11"#), Err(RequestError::Time(_))));
        assert!(matches!(at(r#","time":1.5"#), Err(RequestError::Time(_))));
        assert!(matches!(at(""), Err(RequestError::Time(_))));
        assert!(matches!(
            at(r#","time":0,"frame":0"#),
            Err(RequestError::Time(_))
        ));
        assert!(matches!(
            at(r#","time":0,"quality":0"#),
            Err(RequestError::Quality(0))
        ));
        // Unknown fields are refused, not ignored.
        assert!(request(&format!(r#"{{"camera":{cam},"time":0,"zoom":2}}"#)).is_err());
    }

    /// Frames larger than the viewer renders are refused before anything is allocated.
    #[test]
    fn oversized_frames_are_refused() {
        for (w, h) in [(5000, 10), (4096, 4096), (0, 10)] {
            let text = format!(r#"{{"camera":{},"time":0}}"#, spec(w.max(1), h));
            let mut parsed = request(&text).unwrap();
            parsed.camera.width = w;
            assert!(parsed.resolve(2).is_err(), "{w}×{h} accepted");
        }
        let fine = request(&format!(r#"{{"camera":{},"time":0}}"#, spec(3840, 2160))).unwrap();
        assert!(fine.resolve(2).is_ok());
    }

    /// The copied camera reads back, comment and all, as the camera `tadgs render --camera`
    /// loads: the same f32 values.
    #[test]
    fn camera_ron_round_trips() {
        let camera = Camera::look_at(
            Vec3::new(0.3, -1.7, 2.9),
            Vec3::new(0.1, 0.2, 0.0),
            Vec3::NEG_Y,
            333,
            211,
            0.83,
        );
        let text = camera_ron(&camera, 0.25);
        assert!(text.starts_with("// tadgs render"));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("view.ron");
        std::fs::write(&path, &text).unwrap();
        assert_eq!(crate::io::camera_path::load_camera(&path).unwrap(), camera);
    }

    /// PNG keeps the 8-bit pixels of `Image::to_rgb8` exactly.
    #[test]
    fn png_is_lossless() {
        let mut image = Image::filled(7, 5, [0.2, 0.5, 0.9]);
        image.data[3] = [1.0, 0.0, 0.33];
        let bytes = encode(&image, ImageFormat::Png, 85);
        let decoded = image::load_from_memory(&bytes).unwrap().to_rgb8();
        assert_eq!(decoded, image.to_rgb8());
        let jpeg = encode(&image, ImageFormat::Jpeg, 85);
        assert_eq!(&jpeg[..2], &[0xFF, 0xD8]);
    }
}
