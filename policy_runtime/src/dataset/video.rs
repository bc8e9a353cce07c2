//! Camera streams as MP4 video features (`record --video`), as LeRobot v3.0 stores them:
//! `videos/<feature>/chunk-CCC/file-FFF.mp4`, here one file per episode and camera (the
//! episode's row says which file and its `from_timestamp`/`to_timestamp` in it), encoded by
//! the `ffmpeg` program (`$AMSTACK_FFMPEG` or the PATH's) with libx264, yuv420p, a keyframe
//! every 2 frames (lerobot's `g=2`, for seeking), one thread and bit-exact flags: the same
//! frames give the same bytes.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Stdio};

use super::DatasetError;
use super::layout::DatasetSpec;
use super::write::{AtomicFile, decode_png};

/// H.264 quality (x264's constant rate factor; 18 is visually lossless).
const CRF: &str = "18";

/// Encodes `frames` (PNG bytes, one per frame, all `width` × `height`) at `fps` into the MP4
/// file `root/rel`, atomically (a temporary file beside it, synced, renamed).
pub(crate) fn encode_episode(
    ffmpeg: &Path,
    root: &Path,
    rel: &str,
    frames: &[Vec<u8>],
    fps: u32,
) -> Result<(), DatasetError> {
    let file = AtomicFile::new(root, rel)?;
    let bad = |what: String| DatasetError::invalid(rel, what);
    let first = frames
        .first()
        .ok_or_else(|| bad("no frame to encode".into()))?;
    let (height, width, _) = decode_png(first)?;
    let mut child = Command::new(ffmpeg)
        .args(["-hide_banner", "-loglevel", "error", "-y"])
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
        .args(["-s", &format!("{width}x{height}")])
        .args(["-r", &fps.to_string(), "-i", "-"])
        .args([
            "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", CRF, "-g", "2",
        ])
        .args(["-threads", "1", "-an", "-map_metadata", "-1"])
        .args(["-fflags", "+bitexact", "-flags:v", "+bitexact", "-f", "mp4"])
        .arg(&file.tmp)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| bad(format!("cannot start {}: {e}", ffmpeg.display())))?;
    let written = (|| {
        let mut stdin = child
            .stdin
            .take()
            .ok_or_else(|| bad("ffmpeg has no input pipe".into()))?;
        for (k, png) in frames.iter().enumerate() {
            let (h, w, rgb) = decode_png(png)?;
            if (h, w) != (height, width) {
                return Err(bad(format!(
                    "frame {k} is {w}x{h}, the first {width}x{height}"
                )));
            }
            stdin
                .write_all(&rgb)
                .map_err(|e| bad(format!("ffmpeg stopped reading frames: {e}")))?;
        }
        Ok(())
    })();
    let output = child
        .wait_with_output()
        .map_err(|e| bad(format!("ffmpeg: {e}")));
    let result = written.and_then(|()| {
        let output = output?;
        if !output.status.success() {
            let err = String::from_utf8_lossy(&output.stderr);
            return Err(bad(format!(
                "ffmpeg failed ({}): {}",
                output.status,
                err.lines().last().unwrap_or("no message")
            )));
        }
        file.commit()
    });
    if result.is_err() {
        file.abandon();
    }
    result
}

/// Refuses a video dataset where `what` (merge, export) reads frames from the data files.
pub(crate) fn refuse_video(
    root: &Path,
    spec: &DatasetSpec,
    what: &str,
) -> Result<(), DatasetError> {
    if spec.video {
        return Err(DatasetError::invalid(
            &root.join("meta/info.json").display().to_string(),
            format!(
                "a video dataset (record --video): {what} reads images from the data files and \
                 does not decode videos yet; record without --video for it"
            ),
        ));
    }
    Ok(())
}
