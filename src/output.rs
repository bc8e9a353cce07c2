//! Writing result files: whole or not at all.

use std::io::Write;
use std::path::Path;

use crate::cli_error::bad_input;

/// Checks, before any work is done, that `path` can be written: its directory exists and it
/// is not itself a directory. `flag` names the option in the error (`--json`).
pub fn check_writable(flag: &str, path: &Path) -> anyhow::Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(bad_input(format!(
            "{flag} {}: directory {} does not exist",
            path.display(),
            dir.display()
        )));
    }
    if path.is_dir() {
        return Err(bad_input(format!(
            "{flag} {}: is a directory",
            path.display()
        )));
    }
    Ok(())
}

/// Writes `value` as pretty JSON (non-finite floats become null) to `path` atomically: the
/// text goes to a temporary file beside `path`, which is renamed over it only when complete,
/// so a failed run never leaves a half-written file.
pub fn write_json(path: &Path, value: &serde_json::Value) -> anyhow::Result<()> {
    let mut text = serde_json::to_string_pretty(value)?;
    text.push('\n');
    write_atomically(path, text.as_bytes())
        .map_err(|e| bad_input(format!("cannot write {}: {e}", path.display())))
}

/// Writes `bytes` to `path` atomically, as [`write_json`] does.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    write_atomically(path, bytes)
        .map_err(|e| bad_input(format!("cannot write {}: {e}", path.display())))
}

fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if path.is_dir() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::IsADirectory,
            "is a directory",
        ));
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// A figure for people: six decimals in the usual range, four significant digits in
/// scientific notation for very small or large magnitudes, `0` for an exact zero.
pub fn significant(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".to_owned()
    } else if (1e-3..1e6).contains(&a) {
        format!("{v:.6}")
    } else {
        format!("{v:.3e}")
    }
}

/// Bytes of every file under `path` (0 where it cannot be read).
pub(crate) fn dir_size(path: &Path) -> u64 {
    std::fs::read_dir(path)
        .map(|entries| {
            entries
                .flatten()
                .map(|e| match e.metadata() {
                    Ok(m) if m.is_dir() => dir_size(&e.path()),
                    Ok(m) => m.len(),
                    Err(_) => 0,
                })
                .sum()
        })
        .unwrap_or(0)
}
