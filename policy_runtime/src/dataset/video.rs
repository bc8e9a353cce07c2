//! Camera streams as MP4 video features (`record --video`), as LeRobot v3.0 stores them:
//! `videos/<feature>/chunk-CCC/file-FFF.mp4`, here one file per episode and camera (the
//! episode's row says which file and its `from_timestamp`/`to_timestamp` in it), encoded by
//! the `ffmpeg` program (`$AMSTACK_FFMPEG` or the PATH's) with libx264, yuv420p, a keyframe
//! every 2 frames (lerobot's `g=2`, for seeking), one thread and bit-exact flags: the same
//! frames give the same bytes.

use std::io::{Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};

use super::DatasetError;
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

/// Copies the MP4 `src` (one episode's whole file, from another dataset) to `root/rel`,
/// atomically: a merge keeps the encoded bytes (no re-encoding).
pub(crate) fn copy_video(src: &Path, root: &Path, rel: &str) -> Result<(), DatasetError> {
    let file = AtomicFile::new(root, rel)?;
    if let Err(e) = std::fs::copy(src, &file.tmp) {
        file.abandon();
        return Err(DatasetError::Io {
            path: src.to_owned(),
            source: e,
        });
    }
    file.commit()
}

/// Decodes the MP4 `path` (`width` × `height`) with `ffmpeg` to RGB8 frames, as imageio-ffmpeg
/// reads one (`-pix_fmt rgb24 -vcodec rawvideo -f image2pipe`), and returns the frames at the
/// indices `wanted` (ascending, counted from the file's first frame). A file shorter than the
/// last wanted frame is an error naming it.
pub(crate) fn decode_frames(
    ffmpeg: &Path,
    path: &Path,
    width: usize,
    height: usize,
    wanted: &[usize],
) -> Result<Vec<Vec<u8>>, DatasetError> {
    let shown = path.display().to_string();
    let bad = |what: String| DatasetError::invalid(&shown, what);
    let mut child = Command::new(ffmpeg)
        .args(["-hide_banner", "-loglevel", "error", "-nostdin", "-i"])
        .arg(path)
        .args([
            "-pix_fmt",
            "rgb24",
            "-vcodec",
            "rawvideo",
            "-f",
            "image2pipe",
            "-",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| bad(format!("cannot start {}: {e}", ffmpeg.display())))?;
    let mut stdout = child
        .stdout
        .take()
        .ok_or_else(|| bad("ffmpeg has no output pipe".into()))?;
    let mut frame = vec![0u8; width * height * 3];
    let mut out = Vec::with_capacity(wanted.len());
    let mut next = wanted.iter().peekable();
    let mut k = 0usize;
    let mut short = false;
    while next.peek().is_some() {
        if let Err(e) = stdout.read_exact(&mut frame) {
            short = e.kind() == std::io::ErrorKind::UnexpectedEof;
            if !short {
                let _ = child.kill();
                let _ = child.wait();
                return Err(bad(format!("reading ffmpeg's frames: {e}")));
            }
            break;
        }
        while next.peek().is_some_and(|w| **w == k) {
            out.push(frame.clone());
            next.next();
        }
        k += 1;
    }
    // Every wanted frame is read (or the file ended): the rest is not needed.
    drop(stdout);
    let _ = child.kill();
    let output = child
        .wait_with_output()
        .map_err(|e| bad(format!("ffmpeg: {e}")))?;
    if short {
        let err = String::from_utf8_lossy(&output.stderr);
        return Err(bad(format!(
            "{k} frames of {width}x{height} decoded, frame {} wanted{}",
            wanted.last().copied().unwrap_or(0),
            err.lines()
                .last()
                .map_or(String::new(), |l| format!(" (ffmpeg: {l})"))
        )));
    }
    Ok(out)
}
