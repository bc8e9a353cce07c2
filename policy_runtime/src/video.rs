//! A flight's video: the scene camera (and the EE camera beside it) of every N-th observation,
//! streamed as raw RGB frames to the `ffmpeg` program, which encodes an MP4 (H.264 where
//! ffmpeg has it). As the reference's evaluation videos: 30 fps from every 4th env step.
//!
//! The encoder is a separate program, found as `$AMSTACK_FFMPEG` or `ffmpeg` on the `PATH`
//! (Debian: `apt-get install ffmpeg`); [`ffmpeg_program`] says which one, or that none runs.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

pub use crate::cameras::VideoConfig;
use crate::cameras::{FrameUse, Frames};
use crate::flight::{FlightError, Flow, Observer, Stepped};
use crate::record::RecordError;

/// The environment variable naming the ffmpeg program to use instead of `ffmpeg` on the PATH.
pub const FFMPEG_ENV: &str = "AMSTACK_FFMPEG";

/// The video's frame rate, frames per second (the reference's evaluation videos).
pub const VIDEO_FPS: u32 = 30;

/// The ffmpeg program, checked to run (`ffmpeg -version`); the error is one line saying how
/// to install it.
pub fn ffmpeg_program() -> Result<PathBuf, String> {
    let program =
        std::env::var_os(FFMPEG_ENV).map_or_else(|| PathBuf::from("ffmpeg"), PathBuf::from);
    match Command::new(&program)
        .arg("-version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
    {
        Ok(s) if s.success() => Ok(program),
        Ok(s) => Err(format!(
            "the video encoder '{}' does not run ({s}): install ffmpeg (apt-get install ffmpeg) or \
             set {FFMPEG_ENV} to an ffmpeg program",
            program.display()
        )),
        Err(e) => Err(format!(
            "the video encoder '{}' cannot be started ({e}): install ffmpeg (apt-get install \
             ffmpeg) or set {FFMPEG_ENV} to an ffmpeg program",
            program.display()
        )),
    }
}

impl VideoConfig {
    /// A writer of this video into `path`.
    pub fn writer(&self, path: PathBuf) -> VideoWriter {
        VideoWriter::new(self.program.clone(), path, self.cameras.clone(), self.every)
    }
}

/// An observer writing one MP4: the named cameras of every `every`-th observation, side by side
/// (top-aligned, black below the shorter ones), at [`VIDEO_FPS`].
#[derive(Debug)]
pub struct VideoWriter {
    program: PathBuf,
    path: PathBuf,
    cameras: Vec<String>,
    every: u64,
    encoder: Option<(Child, ChildStdin)>,
    canvas: Vec<u8>,
    size: (u32, u32),
    frames: u64,
}

/// What a finished video holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VideoSummary {
    /// The MP4 written.
    pub path: PathBuf,
    /// Frames encoded.
    pub frames: u64,
    /// Width × height, px.
    pub size: (u32, u32),
}

fn video_error(path: &Path, message: impl std::fmt::Display) -> RecordError {
    RecordError::Image {
        topic: path.display().to_string(),
        message: format!("video: {message}"),
    }
}

impl VideoWriter {
    /// A video of `cameras` (names as in the flight's frames, e.g. `scene_camera`, `ee_camera`)
    /// every `every`-th observation, encoded by `program` into `path`.
    pub fn new(program: PathBuf, path: PathBuf, cameras: Vec<String>, every: u64) -> Self {
        Self {
            program,
            path,
            cameras,
            every: every.max(1),
            encoder: None,
            canvas: Vec::new(),
            size: (0, 0),
            frames: 0,
        }
    }

    fn start_encoder(&mut self, width: u32, height: u32) -> Result<(), RecordError> {
        let mut child = Command::new(&self.program)
            .args(["-hide_banner", "-loglevel", "error", "-y"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
            .args(["-s", &format!("{width}x{height}")])
            .args(["-r", &VIDEO_FPS.to_string(), "-i", "-"])
            .args(["-pix_fmt", "yuv420p", "-movflags", "+faststart"])
            .arg(&self.path)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| {
                video_error(
                    &self.path,
                    format!("cannot start {}: {e}", self.program.display()),
                )
            })?;
        let stdin = child
            .stdin
            .take()
            .ok_or_else(|| video_error(&self.path, "ffmpeg has no input pipe"))?;
        self.encoder = Some((child, stdin));
        self.size = (width, height);
        Ok(())
    }

    /// Adds the images of one observation.
    pub fn frame(&mut self, frames: &Frames) -> Result<(), RecordError> {
        let shown: Vec<_> = self
            .cameras
            .iter()
            .filter_map(|name| frames.get(name))
            .collect();
        if shown.is_empty() {
            return Ok(());
        }
        // Even sizes: yuv420p halves both.
        let width: u32 = shown
            .iter()
            .map(|f| f.image.width)
            .sum::<u32>()
            .next_multiple_of(2);
        let height = shown
            .iter()
            .map(|f| f.image.height)
            .max()
            .unwrap_or(0)
            .next_multiple_of(2);
        if self.encoder.is_none() {
            self.start_encoder(width, height)?;
        } else if self.size != (width, height) {
            return Err(video_error(&self.path, "the cameras changed size"));
        }
        let (w, h) = (width as usize, height as usize);
        self.canvas.clear();
        self.canvas.resize(3 * w * h, 0);
        let mut x0 = 0usize;
        for f in &shown {
            let iw = f.image.width as usize;
            for (row, src) in f.image.rgb.chunks_exact(3 * iw).enumerate().take(h) {
                let at = 3 * (row * w + x0);
                if let Some(dst) = self.canvas.get_mut(at..at + 3 * iw) {
                    dst.copy_from_slice(src);
                }
            }
            x0 += iw;
        }
        let Some((_, stdin)) = &mut self.encoder else {
            return Ok(());
        };
        stdin
            .write_all(&self.canvas)
            .map_err(|e| video_error(&self.path, format!("ffmpeg stopped taking frames: {e}")))?;
        self.frames += 1;
        Ok(())
    }

    /// Closes the video: ffmpeg finishes the file. An encoder that failed is an error with its
    /// last line.
    pub fn finish(mut self) -> Result<Option<VideoSummary>, RecordError> {
        let Some((child, stdin)) = self.encoder.take() else {
            return Ok(None);
        };
        drop(stdin);
        let out = child
            .wait_with_output()
            .map_err(|e| video_error(&self.path, e))?;
        if !out.status.success() {
            let text = String::from_utf8_lossy(&out.stderr);
            let last = text
                .lines()
                .last()
                .unwrap_or("no message")
                .trim()
                .to_owned();
            return Err(video_error(
                &self.path,
                format!("ffmpeg failed ({}): {last}", out.status),
            ));
        }
        Ok(Some(VideoSummary {
            path: self.path.clone(),
            frames: self.frames,
            size: self.size,
        }))
    }
}

impl Observer for VideoWriter {
    fn wants_frames(&self, k: u64) -> FrameUse {
        if k.is_multiple_of(self.every) {
            FrameUse::Stepped
        } else {
            FrameUse::None
        }
    }

    fn stepped(&mut self, step: &mut Stepped<'_>) -> Result<Flow, FlightError> {
        if let Some(frames) = step.frames
            && frames.k.is_multiple_of(self.every)
        {
            self.frame(frames)?;
        }
        Ok(Flow::Continue)
    }
}

impl Drop for VideoWriter {
    fn drop(&mut self) {
        // A flight that ended with an error: stop the encoder (its file is incomplete).
        if let Some((mut child, stdin)) = self.encoder.take() {
            drop(stdin);
            let _ = child.wait();
        }
    }
}
