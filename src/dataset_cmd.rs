//! `amstack dataset`: look at, check, export and merge LeRobot datasets.

use std::path::{Path, PathBuf};

use anyhow::Result;
use policy_runtime::dataset::{
    DatasetError, DatasetReader, export_openpi, is_shard, merge, merge_shards, validate,
};
use serde_json::json;

use crate::cli_error::bad_input;
use crate::output::{check_writable, write_json};

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, clap::Subcommand)]
enum Command {
    /// Episodes, frames, features, fps, size and tasks of a dataset.
    Info {
        /// The dataset folder.
        #[arg(value_name = "DIR")]
        dir: PathBuf,
        /// Write the figures as JSON here.
        #[arg(long, value_name = "FILE")]
        json: Option<PathBuf>,
    },
    /// Check a dataset: the checks of the reference's validator (state and action features,
    /// positive totals and fps, episode lengths summing to the frames, first and last frames'
    /// shapes) and the consistency of every index, timestamp and statistic. One line per
    /// problem; exit 1 if any.
    Validate {
        /// The dataset folder.
        #[arg(value_name = "DIR")]
        dir: PathBuf,
    },
    /// Export to openpi's LeRobot v2.1 layout at the policy rate: frame k of an episode is
    /// raw frame k·(fps / target-hz) (120 → 20 Hz: every 6th, ⌊len/6⌋ frames), with
    /// `ee_image` (and `base_image`), `actions` and the state split into its fields. A video
    /// dataset's frames are decoded from its MP4 files by the ffmpeg program
    /// ($AMSTACK_FFMPEG, else the PATH's).
    #[command(name = "export-openpi")]
    ExportOpenpi {
        /// The dataset folders (the same features; several tasks make one export).
        #[arg(value_name = "DIR", required = true)]
        dirs: Vec<PathBuf>,
        /// The export's folder (must not exist or be empty).
        #[arg(long, value_name = "OUT")]
        out: PathBuf,
        /// The policy's rate, Hz (divides the dataset's fps).
        #[arg(long, default_value_t = 20)]
        target_hz: u32,
    },
    /// Merge datasets of several tasks (the same features) into one multi-task dataset:
    /// episodes re-indexed in the order given, tasks numbered as they appear, statistics
    /// aggregated; video datasets (record --video) with video datasets, each episode's MP4
    /// copied as it is (no re-encoding). Or merge the shards of one recording (`amstack record --shard I/N`, in any
    /// order) into exactly the dataset the unsharded recording writes: they must be of one
    /// recording, each shard once, and hold every attempt the unsharded run decides.
    Merge {
        /// The dataset folders (datasets, or every shard of one recording).
        #[arg(value_name = "DIR", required = true)]
        dirs: Vec<PathBuf>,
        /// The merged dataset's folder (must not exist or be empty).
        #[arg(long, value_name = "OUT")]
        out: PathBuf,
    },
}

fn merge_shard_parts(dirs: &[PathBuf], out: &Path) -> Result<()> {
    // Checked before anything is written: refused merges leave no --out behind.
    if std::fs::read_dir(out).is_ok_and(|mut d| d.next().is_some()) {
        return Err(bad_input(format!("--out {}: not empty", out.display())));
    }
    let existed = out.exists();
    let mut shown = false;
    let mut progress = |e: u64| {
        shown = true;
        eprint!("\rmerge: {e} episodes");
    };
    let merged = merge_shards(dirs, out, &mut progress);
    let merged = match merged {
        Ok(m) => m,
        Err(e) => {
            if shown {
                eprintln!();
            }
            if !existed {
                let _ = std::fs::remove_dir_all(out);
            }
            return Err(match e {
                DatasetError::Invalid { .. } => bad_input(e.to_string()),
                e => anyhow::Error::new(e),
            });
        }
    };
    eprintln!();
    println!(
        "merged {} shards of a recording: {} episodes, {} frames ({} attempts decided{}) in {}",
        dirs.len(),
        merged.writer.episodes(),
        merged.writer.frames(),
        merged.attempts,
        if merged.extra > 0 {
            format!(
                "; {} episodes of the shards past the run's last left out",
                merged.extra
            )
        } else {
            String::new()
        },
        out.display()
    );
    if merged.writer.episodes() < merged.wanted {
        anyhow::bail!(
            "{} of the {} episodes: the recording's attempts were exhausted (as the unsharded run's)",
            merged.writer.episodes(),
            merged.wanted
        );
    }
    Ok(())
}

fn open(dir: &Path) -> Result<DatasetReader> {
    if !dir.join("meta/info.json").is_file() {
        return Err(bad_input(format!(
            "{}: not a dataset (no meta/info.json)",
            dir.display()
        )));
    }
    DatasetReader::open(dir).map_err(|e| bad_input(format!("{}: {e}", dir.display())))
}

fn fresh_out(out: &Path) -> Result<()> {
    if std::fs::read_dir(out).is_ok_and(|mut d| d.next().is_some()) {
        return Err(bad_input(format!("--out {}: not empty", out.display())));
    }
    std::fs::create_dir_all(out)
        .map_err(|e| bad_input(format!("--out {}: cannot create it: {e}", out.display())))
}

pub fn run(args: &Args) -> Result<()> {
    match &args.command {
        Command::Info { dir, json } => {
            if let Some(p) = json {
                check_writable("--json", p)?;
            }
            let r = open(dir)?;
            let size = crate::output::dir_size(dir);
            let features: Vec<_> = r
                .spec
                .features()
                .iter()
                .map(|f| json!({"key": f.key, "dtype": f.dtype.name(), "shape": f.shape}))
                .collect();
            let value = json!({
                "dataset": dir.display().to_string(),
                "codebase_version": r.info["codebase_version"],
                "robot_type": r.spec.robot_type,
                "episodes": r.total_episodes,
                "frames": r.total_frames,
                "fps": r.spec.fps,
                "duration_s": r.total_frames as f64 / f64::from(r.spec.fps),
                "action_semantics": r.spec.action_semantics.name(),
                "state_keys": r.spec.state_keys,
                "tasks": r.tasks,
                "features": features,
                "bytes": size,
                "recording": r.recording,
                "shard": r.info["ambench"].get("shard").map(|s| json!({
                    "index": s["index"], "count": s["count"], "run": s["run"],
                    "attempts_decided": s["attempts"].as_array().map_or(0, Vec::len),
                })),
            });
            println!(
                "{}: LeRobot {} dataset of {} ({}), {} episodes, {} frames at {} fps ({:.1} s), {:.1} MB",
                dir.display(),
                r.info["codebase_version"].as_str().unwrap_or("?"),
                r.spec.robot_type,
                r.spec.action_semantics.name(),
                r.total_episodes,
                r.total_frames,
                r.spec.fps,
                r.total_frames as f64 / f64::from(r.spec.fps),
                size as f64 / 1e6
            );
            for f in r.spec.features() {
                println!("  {:<32} {:<8} {:?}", f.key, f.dtype.name(), f.shape);
            }
            println!("  state keys: {}", r.spec.state_keys.join(" "));
            if let Some(shard) = value["shard"].as_object() {
                println!(
                    "  shard {}/{} of a recording of {} episodes ({} attempts decided): merge the shards with `amstack dataset merge`",
                    shard["index"],
                    shard["count"],
                    shard["run"]["episodes"],
                    shard["attempts_decided"]
                );
            }
            for (i, t) in r.tasks.iter().enumerate() {
                println!("  task {i}: {t}");
            }
            if let Some(p) = json {
                write_json(p, &value)?;
            }
            Ok(())
        }
        Command::Validate { dir } => {
            let _ = open(dir)?;
            let problems = validate(dir);
            for p in &problems {
                println!("{}: {p}", dir.display());
            }
            if problems.is_empty() {
                let r = open(dir)?;
                println!(
                    "{}: valid ({} episodes, {} frames)",
                    dir.display(),
                    r.total_episodes,
                    r.total_frames
                );
                Ok(())
            } else {
                anyhow::bail!("{} problem(s) in {}", problems.len(), dir.display())
            }
        }
        Command::ExportOpenpi {
            dirs,
            out,
            target_hz,
        } => {
            for d in dirs {
                open(d)?;
            }
            let existed = out.exists();
            fresh_out(out)?;
            let mut shown = false;
            let mut progress = |e: u64| {
                shown = true;
                eprint!("\rexport-openpi: {e} episodes");
            };
            let export = export_openpi(dirs, out, *target_hz, &mut progress);
            let export = export.map_err(|e| failed_out(e, shown, existed, out))?;
            eprintln!();
            println!(
                "exported {} episodes, {} frames at {} Hz (every {}th of {} raw frames){} to {}",
                export.episodes,
                export.frames,
                target_hz,
                export.stride,
                export.raw_frames,
                if export.images {
                    ""
                } else {
                    ", without images (none recorded)"
                },
                out.display()
            );
            Ok(())
        }
        Command::Merge { dirs, out } => {
            for d in dirs {
                open(d)?;
            }
            let shards: Vec<&PathBuf> = dirs.iter().filter(|d| is_shard(d)).collect();
            if !shards.is_empty() {
                if let Some(whole) = dirs.iter().find(|d| !is_shard(d)) {
                    return Err(bad_input(format!(
                        "{} is a shard of a recording, {} is not: merge the shards of one recording first, then the datasets",
                        shards[0].display(),
                        whole.display()
                    )));
                }
                return merge_shard_parts(dirs, out);
            }
            let existed = out.exists();
            fresh_out(out)?;
            let mut shown = false;
            let mut progress = |e: u64| {
                shown = true;
                eprint!("\rmerge: {e} episodes");
            };
            let w = merge(dirs, out, &mut progress);
            let w = w.map_err(|e| failed_out(e, shown, existed, out))?;
            eprintln!();
            println!(
                "merged {} datasets: {} episodes, {} frames in {}",
                dirs.len(),
                w.episodes(),
                w.frames(),
                out.display()
            );
            Ok(())
        }
    }
}

/// A command writing `out` failed with `e`: the error on a line of its own after the
/// progress (`shown`), and no half-written `out` (emptied if it `existed`, else removed).
fn failed_out(e: DatasetError, shown: bool, existed: bool, out: &Path) -> anyhow::Error {
    if shown {
        eprintln!();
    }
    if existed {
        let _ = std::fs::remove_dir_all(out).and_then(|()| std::fs::create_dir(out));
    } else {
        let _ = std::fs::remove_dir_all(out);
    }
    match e {
        DatasetError::Invalid { .. } => bad_input(e.to_string()),
        e => anyhow::Error::new(e),
    }
}
