//! MP4 videos through the system `ffmpeg`: raw RGB frames are piped to it (H.264, yuv420p,
//! which every player opens). Nothing is downloaded; without `ffmpeg` callers write PNG frames.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

use super::image::Image;

/// A video could not be made.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    /// `ffmpeg` could not be started (not on `PATH`) or waited for.
    #[error("cannot run ffmpeg: {0}")]
    Spawn(std::io::Error),
    /// `ffmpeg` quit early or exited with an error while encoding the video at `path`.
    #[error("ffmpeg failed on {}: {message}", path.display())]
    Ffmpeg {
        /// The video being made.
        path: PathBuf,
        /// ffmpeg's error output, or the exit status or pipe error when it printed nothing.
        message: String,
    },
    /// The encoded video could not be moved into place at `path`.
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The video file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A pushed frame's size differs from the video's.
    #[error("frame {index} is {got:?}, the video is {expected:?}")]
    FrameSize {
        /// Index of the frame in the video, from 0.
        index: usize,
        /// The frame's (width, height) in pixels.
        got: (usize, usize),
        /// The video's (width, height) in pixels.
        expected: (usize, usize),
    },
}

/// Whether an `ffmpeg` executable runs from `PATH`.
pub fn ffmpeg_available() -> bool {
    Command::new("ffmpeg")
        .arg("-version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// An MP4 being encoded: frames go to ffmpeg's standard input; ffmpeg writes a temporary file
/// that [`VideoWriter::finish`] moves into place atomically.
pub struct VideoWriter {
    child: Child,
    stdin: Option<ChildStdin>,
    temp: PathBuf,
    path: PathBuf,
    size: (usize, usize),
    frames: usize,
}

impl VideoWriter {
    /// Starts ffmpeg for a `width × height` video at `fps` frames per second written to `path`.
    pub fn start(path: &Path, width: usize, height: usize, fps: f32) -> Result<Self, VideoError> {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "video".into());
        let temp = path.with_file_name(format!(".{name}.{}.mp4", std::process::id()));
        let mut child = Command::new("ffmpeg")
            .args(["-hide_banner", "-loglevel", "error", "-y"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
            .args(["-s", &format!("{width}x{height}"), "-r", &fps.to_string()])
            .args(["-i", "-", "-an", "-c:v", "libx264", "-crf", "18"])
            // yuv420p needs even sizes: pad by one pixel where needed.
            .args([
                "-vf",
                "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                "-pix_fmt",
                "yuv420p",
            ])
            .args(["-movflags", "+faststart", "-f", "mp4"])
            .arg(&temp)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(VideoError::Spawn)?;
        let stdin = child.stdin.take();
        Ok(Self {
            child,
            stdin,
            temp,
            path: path.to_path_buf(),
            size: (width, height),
            frames: 0,
        })
    }

    /// Appends one frame (of the video's size).
    pub fn push(&mut self, frame: &Image) -> Result<(), VideoError> {
        if (frame.width, frame.height) != self.size {
            return Err(VideoError::FrameSize {
                index: self.frames,
                got: (frame.width, frame.height),
                expected: self.size,
            });
        }
        let stdin = self.stdin.as_mut().expect("open until finish");
        if let Err(e) = stdin.write_all(frame.to_rgb8().as_raw()) {
            // ffmpeg quit early: its own message says why.
            return Err(self.failure(e.to_string()));
        }
        self.frames += 1;
        Ok(())
    }

    /// Closes the stream, waits for ffmpeg and moves the video into place.
    pub fn finish(mut self) -> Result<PathBuf, VideoError> {
        drop(self.stdin.take());
        let status = self.child.wait().map_err(VideoError::Spawn)?;
        if !status.success() {
            return Err(self.failure(format!("exit status {status}")));
        }
        let result = std::fs::read(&self.temp)
            .and_then(|bytes| super::write_atomic(&self.path, &bytes))
            .map_err(|source| VideoError::Write {
                path: self.path.clone(),
                source,
            });
        let _ = std::fs::remove_file(&self.temp);
        result.map(|()| self.path.clone())
    }

    /// ffmpeg's error output (or `fallback`), after it has exited; removes the partial file.
    fn failure(&mut self, fallback: String) -> VideoError {
        drop(self.stdin.take());
        let _ = self.child.wait();
        let mut message = String::new();
        if let Some(mut stderr) = self.child.stderr.take() {
            let _ = stderr.read_to_string(&mut message);
        }
        let _ = std::fs::remove_file(&self.temp);
        let message = message.trim();
        VideoError::Ffmpeg {
            path: self.path.clone(),
            message: if message.is_empty() {
                fallback
            } else {
                message.to_string()
            },
        }
    }
}
