//! Temporal segments: a long sequence split into overlapping frame ranges, each trained as an
//! ordinary run, then merged into one model of the whole sequence.
//!
//! Every segment trains in the whole sequence's time ([`crate::scene::Segment`]): frame f is at
//! f/(T − 1) in each of them, so their Gaussians need no time map to live in one model. The
//! merge concatenates the segments' Gaussians and gives each a [`TimeWindow`] over the frames
//! its segment owns; neighbouring windows share an end, half a frame before the next
//! segment's first owned frame, and cross-fade over `fade_frames` around it. The overlap is
//! trained by both neighbours, so each is still fitted to the frames its window reaches into.
//!
//! Scheduling is not ours: `tadgs segment plan --slurm` writes a Slurm job array and
//! `scripts/ray_segments.py` submits one Ray task per segment; both only run `tadgs train` and
//! `tadgs segment merge`.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::components::TimeWindow;
use crate::io::model::Model;
use crate::scene::{SceneConfig, Segment};

/// File name of the plan inside a plan folder.
pub const PLAN_FILE: &str = "plan.ron";
/// File name of the whole-sequence scene inside a plan folder.
pub const BASE_SCENE_FILE: &str = "scene.ron";

/// A plan or a merge is inconsistent.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SegmentError {
    /// The requested split is impossible (more segments than frames, no segment).
    #[error("cannot split {frames} frames into {segments} segments: {reason}")]
    Split {
        /// Frames of the sequence.
        frames: usize,
        /// Segments asked for.
        segments: usize,
        /// Why not.
        reason: &'static str,
    },
    /// The plan's frame ranges do not tile the sequence, or a segment does not train the
    /// frames it owns.
    #[error("plan: {0}")]
    Plan(String),
    /// A segment's trained model does not fit the plan or the other segments.
    #[error("segment {index} ({run}): {message}")]
    Segment {
        /// Index of the segment in the plan.
        index: usize,
        /// Its run folder, as the plan names it.
        run: String,
        /// What is wrong.
        message: String,
    },
}

/// One segment of a plan: the frames it trains on and the frames it owns in the merge.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct PlannedSegment {
    /// Its run folder, relative to the plan's folder.
    pub run: String,
    /// First frame trained (owned frames plus the overlap before them).
    pub first_frame: usize,
    /// Last frame trained (inclusive).
    pub last_frame: usize,
    /// First frame it draws in the merged model.
    pub owned_first: usize,
    /// Last frame it draws in the merged model (inclusive).
    pub owned_last: usize,
}

impl PlannedSegment {
    /// Its run folder in the plan folder `plan_dir`.
    pub fn run_folder(&self, plan_dir: &Path) -> PathBuf {
        plan_dir.join(&self.run)
    }

    /// Its scene file in the plan folder `plan_dir` (`segment-K.ron` beside the run folder).
    pub fn scene_file(&self, plan_dir: &Path) -> PathBuf {
        plan_dir.join(format!("{}.ron", self.run))
    }

    /// The scene setting that restricts a run to this segment's frames.
    pub fn segment(&self) -> Segment {
        Segment {
            first_frame: self.first_frame,
            last_frame: self.last_frame,
        }
    }
}

/// A split of a sequence into segments (the plan file `plan.ron`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SegmentPlan {
    /// Frames T of the whole sequence.
    pub frame_count: usize,
    /// Frames trained by both neighbours on each side of a boundary.
    pub overlap_frames: usize,
    /// Width of the cross-fade at each boundary, in frames (1: every frame is drawn by one
    /// segment, times between frames blend the two).
    pub fade_frames: f32,
    /// The segments in time order.
    pub segments: Vec<PlannedSegment>,
}

impl SegmentPlan {
    /// Splits `frame_count` frames into `count` segments of (nearly) equal owned length, each
    /// trained on `overlap` more frames on each side where there are frames, with a cross-fade
    /// of `fade_frames` (at most 2·`overlap` + 1, so the fade stays within trained frames).
    pub fn new(
        frame_count: usize,
        count: usize,
        overlap: usize,
        fade_frames: f32,
    ) -> Result<Self, SegmentError> {
        let split = |reason| SegmentError::Split {
            frames: frame_count,
            segments: count,
            reason,
        };
        if count == 0 {
            return Err(split("ask for at least one segment"));
        }
        if count > frame_count {
            return Err(split("each segment needs a frame of its own"));
        }
        let boundary = |k: usize| (k * frame_count + count / 2) / count;
        let segments = (0..count)
            .map(|k| {
                let (owned_first, owned_last) = (boundary(k), boundary(k + 1) - 1);
                PlannedSegment {
                    run: format!("segment-{k}"),
                    first_frame: owned_first.saturating_sub(overlap),
                    last_frame: (owned_last + overlap).min(frame_count - 1),
                    owned_first,
                    owned_last,
                }
            })
            .collect();
        let plan = Self {
            frame_count,
            overlap_frames: overlap,
            fade_frames,
            segments,
        };
        plan.validate()?;
        Ok(plan)
    }

    /// Checks that the owned ranges tile the sequence in order, that every segment trains the
    /// frames it owns and those its fade reaches, and that run folders are distinct.
    pub fn validate(&self) -> Result<(), SegmentError> {
        let plan = |message: String| Err(SegmentError::Plan(message));
        let t = self.frame_count;
        if t == 0 {
            return plan("frame_count is 0".into());
        }
        if self.segments.is_empty() {
            return plan("there is no segment".into());
        }
        if !(self.fade_frames.is_finite() && self.fade_frames >= 0.0) {
            return plan(format!("fade_frames is {}, expected ≥ 0", self.fade_frames));
        }
        let reach = self.fade_frames / 2.0 - 0.5;
        let mut next_owned = 0;
        for (index, s) in self.segments.iter().enumerate() {
            let name = format!("segment {index} ({})", s.run);
            if s.owned_first != next_owned {
                return plan(format!(
                    "{name} owns frames from {}, but the previous segment ends at frame {} \
                     (owned ranges must follow each other without gap or overlap)",
                    s.owned_first,
                    next_owned as isize - 1
                ));
            }
            if s.owned_last < s.owned_first || s.owned_last >= t {
                return plan(format!(
                    "{name} owns frames {} to {}, not a range within the {t} frames",
                    s.owned_first, s.owned_last
                ));
            }
            if s.first_frame > s.owned_first || s.last_frame < s.owned_last || s.last_frame >= t {
                return plan(format!(
                    "{name} trains frames {} to {} but owns {} to {}: it must train every \
                     frame it owns, within the {t} frames",
                    s.first_frame, s.last_frame, s.owned_first, s.owned_last
                ));
            }
            // The fade reaches `reach` frames past the owned frames at inner boundaries.
            let before = if index > 0 { reach } else { 0.0 };
            let after = if index + 1 < self.segments.len() {
                reach
            } else {
                0.0
            };
            if (s.first_frame as f32) > s.owned_first as f32 - before
                || (s.last_frame as f32) < s.owned_last as f32 + after
            {
                return plan(format!(
                    "{name}: a fade of {} frames reaches {reach} frames past its owned frames \
                     {} to {}, beyond the frames it trains ({} to {}); lower fade_frames or \
                     raise the overlap",
                    self.fade_frames, s.owned_first, s.owned_last, s.first_frame, s.last_frame
                ));
            }
            next_owned = s.owned_last + 1;
        }
        if next_owned != t {
            return plan(format!(
                "the segments own frames up to {}, but the sequence has {t} frames",
                next_owned - 1
            ));
        }
        let mut runs: Vec<&str> = self.segments.iter().map(|s| s.run.as_str()).collect();
        runs.sort_unstable();
        if let Some(twice) = runs.windows(2).find(|w| w[0] == w[1]) {
            return plan(format!(
                "two segments train into the same run folder {}",
                twice[0]
            ));
        }
        Ok(())
    }

    /// The time window of segment `index` in the merged model: from half a frame before its
    /// first owned frame to half a frame after its last, open at the sequence's ends.
    pub fn window(&self, index: usize) -> TimeWindow {
        let intervals = (self.frame_count.max(2) - 1) as f32;
        let segment = &self.segments[index];
        let last = index + 1 == self.segments.len();
        TimeWindow {
            start: if index == 0 {
                TimeWindow::ALWAYS.start
            } else {
                (segment.owned_first as f32 - 0.5) / intervals
            },
            end: if last {
                TimeWindow::ALWAYS.end
            } else {
                (segment.owned_last as f32 + 0.5) / intervals
            },
            fade: self.fade_frames / intervals,
        }
    }

    /// The scene segment `index` trains with: `base` restricted to its frames, writing into
    /// `run_folder`.
    pub fn segment_scene(
        &self,
        base: &SceneConfig,
        index: usize,
        run_folder: &Path,
    ) -> SceneConfig {
        let planned = &self.segments[index];
        let mut scene = base.clone();
        scene.name = format!("{}-{}", base.name, planned.run);
        scene.segment = Some(planned.segment());
        scene.output = run_folder.to_string_lossy().into_owned();
        scene
    }

    /// Joins the segments' trained models (in plan order) into one model of the whole
    /// sequence: every Gaussian of segment k with segment k's [`SegmentPlan::window`]. The
    /// models must share the deformation settings and know the plan's frame count.
    pub fn merge(&self, models: &[Model]) -> Result<Model, SegmentError> {
        self.validate()?;
        if models.len() != self.segments.len() {
            return Err(SegmentError::Plan(format!(
                "{} models for {} segments",
                models.len(),
                self.segments.len()
            )));
        }
        let mut merged = Model {
            frame_count: Some(self.frame_count),
            time_windows: Some(Vec::new()),
            ..Model::default()
        };
        for (index, (segment, model)) in self.segments.iter().zip(models).enumerate() {
            let fail = |message: String| SegmentError::Segment {
                index,
                run: segment.run.clone(),
                message,
            };
            if model.frame_count != Some(self.frame_count) {
                return Err(fail(format!(
                    "its model is of a {}-frame sequence, the plan's has {} frames",
                    model
                        .frame_count
                        .map_or("unknown".to_string(), |n| n.to_string()),
                    self.frame_count
                )));
            }
            if model.time_windows.is_some() {
                return Err(fail("its model is already a merged model".into()));
            }
            if model.shared_motion.is_some() {
                return Err(fail(
                    "its model has shared motion bases (`model.shared_motion`), which the \
                     segments of a merged model cannot share"
                        .into(),
                ));
            }
            let config = model.config.clone().unwrap_or_default();
            match &merged.config {
                None => merged.config = Some(config),
                Some(first) => {
                    let mut ours = config;
                    ours.sh_degree = first.sh_degree;
                    if &ours != first {
                        return Err(fail(
                            "its deformation settings (`model` of its scene) differ from \
                             segment 0's"
                                .into(),
                        ));
                    }
                }
            }
            merged.sh_degree = merged.sh_degree.max(model.sh_degree);
            merged.gaussians.extend_from_slice(&model.gaussians);
            let window = self.window(index);
            if let Some(windows) = merged.time_windows.as_mut() {
                windows.extend(std::iter::repeat_n(window, model.gaussians.len()));
            }
        }
        if let Some(config) = merged.config.as_mut() {
            config.sh_degree = config.sh_degree.max(merged.sh_degree);
        }
        Ok(merged)
    }
}

/// Where a setting of `trained` differs from `expected`, as the first differing line of their
/// RON texts (the run folder and name aside); `None` when they agree.
pub fn settings_difference(expected: &SceneConfig, trained: &SceneConfig) -> Option<String> {
    let text = |scene: &SceneConfig| {
        let mut scene = scene.clone();
        scene.output.clear();
        scene.name.clear();
        ron::ser::to_string_pretty(&scene, ron::ser::PrettyConfig::default()).unwrap_or_default()
    };
    let (expected, trained) = (text(expected), text(trained));
    expected
        .lines()
        .zip(trained.lines())
        .find(|(a, b)| a != b)
        .map(|(a, b)| format!("the plan has `{}`, the run `{}`", a.trim(), b.trim()))
        .or_else(|| {
            (expected.lines().count() != trained.lines().count())
                .then(|| "the scene files differ in length".to_string())
        })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::deform::window_factor;

    #[test]
    fn plan_tiles_the_sequence_with_overlap() {
        let plan = SegmentPlan::new(150, 3, 5, 1.0).unwrap();
        let ranges: Vec<_> = plan
            .segments
            .iter()
            .map(|s| (s.first_frame, s.owned_first, s.owned_last, s.last_frame))
            .collect();
        assert_eq!(
            ranges,
            vec![(0, 0, 49, 54), (45, 50, 99, 104), (95, 100, 149, 149)]
        );
        // Uneven splits differ by at most one frame.
        let uneven = SegmentPlan::new(10, 3, 0, 1.0).unwrap();
        let lengths: Vec<_> = uneven
            .segments
            .iter()
            .map(|s| s.owned_last + 1 - s.owned_first)
            .collect();
        assert_eq!(lengths, vec![3, 4, 3]);
    }

    #[test]
    fn every_frame_is_drawn_by_exactly_one_segment() {
        let plan = SegmentPlan::new(150, 3, 5, 1.0).unwrap();
        for frame in 0..150 {
            let t = frame as f32 / 149.0;
            let factors: Vec<f32> = (0..3).map(|k| window_factor(&plan.window(k), t)).collect();
            let owner = plan
                .segments
                .iter()
                .position(|s| (s.owned_first..=s.owned_last).contains(&frame))
                .unwrap();
            for (k, f) in factors.iter().enumerate() {
                let expected = if k == owner { 1.0 } else { 0.0 };
                assert!(
                    (f - expected).abs() < 1e-4,
                    "frame {frame}, segment {k}: {f}"
                );
            }
        }
        // Between the two frames of a boundary both segments blend, summing to 1.
        let t = 49.5 / 149.0;
        let (a, b) = (
            window_factor(&plan.window(0), t),
            window_factor(&plan.window(1), t),
        );
        assert!(
            (a - 0.5).abs() < 1e-3 && (a + b - 1.0).abs() < 1e-5,
            "{a} {b}"
        );
    }

    #[test]
    fn bad_plans_are_refused() {
        assert!(matches!(
            SegmentPlan::new(2, 3, 0, 1.0),
            Err(SegmentError::Split { .. })
        ));
        let good = SegmentPlan::new(30, 3, 2, 1.0).unwrap();
        let mut gap = good.clone();
        gap.segments[1].owned_first += 1;
        gap.segments[1].first_frame += 1;
        let message = gap.validate().unwrap_err().to_string();
        assert!(message.contains("without gap or overlap"), "{message}");
        let mut untrained = good.clone();
        untrained.segments[2].first_frame = untrained.segments[2].owned_first + 1;
        let message = untrained.validate().unwrap_err().to_string();
        assert!(
            message.contains("must train every frame it owns"),
            "{message}"
        );
        let mut wide = good.clone();
        wide.fade_frames = 6.0;
        let message = wide.validate().unwrap_err().to_string();
        assert!(message.contains("raise the overlap"), "{message}");
        let mut same_run = good;
        same_run.segments[2].run = "segment-0".into();
        let message = same_run.validate().unwrap_err().to_string();
        assert!(message.contains("same run folder"), "{message}");
    }
}
