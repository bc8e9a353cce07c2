#!/usr/bin/env python3
"""Independent check of a LeRobot v3.0 dataset written by `amstack record` (and of its
`amstack dataset export-openpi` output), with pyarrow and numpy only: code that is not ours
reads every file and checks that info.json, meta/tasks.parquet, meta/episodes/*.parquet and
meta/stats.json agree with the data. The MP4 files of a video dataset (`record --video`) are
decoded with imageio-ffmpeg's ffmpeg: each episode's file has its frames (count, size, fps) and
its row's from/to timestamps span them. The openpi export's `ee_image` is the source's image
at every 6th frame (a video dataset: the frame imageio-ffmpeg decodes at that timestamp,
pixel for pixel; its PNG read with Pillow).

    dataset_check.py DIR [--openpi OUT] [--json]

Prints one line per problem (or a JSON report with --json); exit 0 when there is none, 1
otherwise, 2 on bad usage.
"""

import argparse
import glob
import json
import os
import struct
import sys

import numpy as np
import pyarrow.parquet as pq

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
STAT_KEYS = ["min", "max", "mean", "std", "count", "q01", "q10", "q50", "q90", "q99"]
STATE_DIMS = {"ee_pos": 3, "ee_quat": 4, "gripper_width": 1, "base_pos": 3, "base_quat": 4,
              "base_lin_vel": 3, "base_ang_vel": 3}


def png_size(data):
    """(width, height) from a PNG's IHDR chunk, or None."""
    if not data or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", data[16:24])


def close(a, b, rtol=1e-5, atol=1e-6):
    return np.allclose(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64), rtol=rtol, atol=atol)


def check_dataset(root, problems, report):
    info = json.load(open(os.path.join(root, "meta/info.json")))
    feats = info["features"]
    if info.get("codebase_version") != "v3.0":
        problems.append(f"info.json: codebase_version {info.get('codebase_version')!r}")
    for key in ("observation.state", "action"):
        if key not in feats:
            problems.append(f"info.json: no feature {key}")
    fps = info["fps"]
    if not (fps > 0 and info["total_episodes"] > 0 and info["total_frames"] > 0):
        problems.append("info.json: fps, total_episodes and total_frames must be positive")
    if "ambench" not in info or "action_semantics" not in info["ambench"] or "state_keys" not in info["ambench"]:
        problems.append("info.json: no ambench block with action_semantics and state_keys")

    tasks_table = pq.read_table(os.path.join(root, "meta/tasks.parquet"))
    pandas_meta = json.loads(tasks_table.schema.metadata[b"pandas"])
    index_column = pandas_meta["index_columns"][0]
    tasks = dict(zip(tasks_table.column("task_index").to_pylist(), tasks_table.column(index_column).to_pylist()))
    if sorted(tasks) != list(range(len(tasks))) or info["total_tasks"] != len(tasks):
        problems.append(f"tasks.parquet: task_index {sorted(tasks)}, total_tasks {info['total_tasks']}")

    ep_files = sorted(glob.glob(os.path.join(root, "meta/episodes/*/*.parquet")))
    eps = [pq.read_table(f) for f in ep_files]
    ep_rows = [row for t in eps for row in t.to_pylist()]
    ep_rows.sort(key=lambda r: r["episode_index"])
    if [r["episode_index"] for r in ep_rows] != list(range(info["total_episodes"])):
        problems.append("meta/episodes: episode_index is not 0..total_episodes-1")
    if sum(r["length"] for r in ep_rows) != info["total_frames"]:
        problems.append("meta/episodes: lengths do not sum to total_frames")

    data_files = sorted(glob.glob(os.path.join(root, "data/*/*.parquet")))
    tables = [pq.read_table(f) for f in data_files]
    names = [c for c in feats if feats[c]["dtype"] != "video"]
    for f, t in zip(data_files, tables):
        if sorted(t.column_names) != sorted(names):
            problems.append(f"{f}: columns {t.column_names}, features {names}")
    n = sum(t.num_rows for t in tables)
    report["frames"] = n
    report["episodes"] = len(ep_rows)
    if n != info["total_frames"]:
        problems.append(f"data: {n} rows, total_frames {info['total_frames']}")

    def col(name):
        return np.concatenate([t.column(name).combine_chunks().to_numpy(zero_copy_only=False) for t in tables])

    def vec(name, dim):
        out = []
        for t in tables:
            c = t.column(name).combine_chunks()
            out.append(c.flatten().to_numpy().reshape(-1, dim))
        return np.concatenate(out)

    index, episode, frame = col("index"), col("episode_index"), col("frame_index")
    ts, task = col("timestamp"), col("task_index")
    order = np.argsort(index, kind="stable")
    if not np.array_equal(index[order], np.arange(n)):
        problems.append("data: index is not 0..total_frames-1")
    state = vec("observation.state", feats["observation.state"]["shape"][0])[order]
    action = vec("action", feats["action"]["shape"][0])[order]
    episode, frame, ts, task = episode[order], frame[order], ts[order], task[order]
    if state.dtype != np.float32 or action.dtype != np.float32 or ts.dtype != np.float32:
        problems.append("data: state, action and timestamp must be float32")
    for r in ep_rows:
        a, b = r["dataset_from_index"], r["dataset_to_index"]
        e = r["episode_index"]
        if b - a != r["length"]:
            problems.append(f"episode {e}: to - from != length")
            continue
        if not (episode[a:b] == e).all():
            problems.append(f"episode {e}: episode_index of rows [{a}, {b}) differs")
        if not np.array_equal(frame[a:b], np.arange(b - a)):
            problems.append(f"episode {e}: frame_index is not 0..length-1")
        if not np.array_equal(ts[a:b], (np.arange(b - a) / fps).astype(np.float32)):
            problems.append(f"episode {e}: timestamp != frame_index / fps")
        if any(tasks.get(int(t)) not in r["tasks"] for t in np.unique(task[a:b])):
            problems.append(f"episode {e}: task_index not among its tasks {r['tasks']}")
        for key, values in (("observation.state", state[a:b]), ("action", action[a:b])):
            s = {k: r[f"stats/{key}/{k}"] for k in STAT_KEYS}
            if not (close(s["min"], values.min(0)) and close(s["max"], values.max(0))
                    and close(s["mean"], values.astype(np.float64).mean(0))
                    and close(s["std"], values.astype(np.float64).std(0), atol=1e-5)
                    and s["count"] == [b - a]):
                problems.append(f"episode {e}: stats of {key} disagree with its frames")
            q = np.array([s[k] for k in STAT_KEYS[5:]])
            if not ((q >= np.array(s["min"]) - 1e-6).all() and (q <= np.array(s["max"]) + 1e-6).all()
                    and (np.diff(q, axis=0) >= -1e-9).all()):
                problems.append(f"episode {e}: quantiles of {key} not ordered within [min, max]")
    if not np.isfinite(state).all() or not np.isfinite(action).all():
        problems.append("data: non-finite state or action")

    stats = json.load(open(os.path.join(root, "meta/stats.json")))
    for key, values in (("observation.state", state), ("action", action)):
        s = stats.get(key, {})
        if not (close(s.get("min"), values.min(0)) and close(s.get("max"), values.max(0))
                and close(s.get("mean"), values.astype(np.float64).mean(0))
                and close(s.get("std"), values.astype(np.float64).std(0), atol=1e-5)
                and s.get("count") == [n]):
            problems.append(f"stats.json: {key} disagrees with the data")
    for key in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        if not all(k in stats.get(key, {}) for k in STAT_KEYS):
            problems.append(f"stats.json: {key} lacks some of {STAT_KEYS}")
    for key, ft in feats.items():
        if ft["dtype"] != "image":
            continue
        h, w, c = ft["shape"]
        s = stats.get(key, {})
        if np.array(s.get("mean")).shape != (3, 1, 1) or not (0 <= np.array(s["min"])).all() or not (np.array(s["max"]) <= 1).all():
            problems.append(f"stats.json: {key} is not per channel (3,1,1) in [0, 1]")
        for t in tables:
            for item in t.column(key).to_pylist():
                if png_size(item["bytes"]) != (w, h):
                    problems.append(f"data: {key} is not a {w}x{h} PNG")
                    break
    videos = [k for k, ft in feats.items() if ft["dtype"] == "video"]
    if videos:
        check_videos(root, info, videos, ep_rows, stats, problems, report)
    return {"root": root, "info": info, "tasks": tasks, "state": state, "action": action, "episodes": ep_rows,
            "tables": tables, "order": order}


def check_videos(root, info, videos, ep_rows, stats, problems, report):
    import imageio_ffmpeg

    fps = info["fps"]
    template = info.get("video_path") or ""
    decoded = 0
    for key in videos:
        ft = info["features"][key]
        h, w, _ = ft["shape"]
        vi = ft.get("info", {})
        if vi.get("video.fps") != fps or vi.get("video.height") != h or vi.get("video.width") != w:
            problems.append(f"info.json: {key}.info {vi} does not say {w}x{h} at {fps} fps")
        s = stats.get(key, {})
        if np.array(s.get("mean")).shape != (3, 1, 1):
            problems.append(f"stats.json: {key} is not per channel (3,1,1)")
        for r in ep_rows:
            e = r["episode_index"]
            c, f = r[f"videos/{key}/chunk_index"], r[f"videos/{key}/file_index"]
            t0, t1 = r[f"videos/{key}/from_timestamp"], r[f"videos/{key}/to_timestamp"]
            path = os.path.join(root, template.format(video_key=key, chunk_index=c, file_index=f))
            if not os.path.isfile(path):
                problems.append(f"episode {e}: {path} is missing")
                continue
            reader = imageio_ffmpeg.read_frames(path)
            meta = next(reader)
            frames = 0
            for frame in reader:
                if len(frame) != h * w * 3:
                    problems.append(f"{path}: a frame of {len(frame)} bytes, not {w}x{h} RGB")
                    break
                frames += 1
            if tuple(meta["size"]) != (w, h) or abs(meta["fps"] - fps) > 1e-6:
                problems.append(f"{path}: {meta['size']} at {meta['fps']} fps, not {w}x{h} at {fps}")
            # The episode's frames in the file: [from, to) at fps.
            first, last = round(t0 * fps), round(t1 * fps)
            if not (abs(t0 * fps - first) < 1e-6 and abs(t1 * fps - last) < 1e-6
                    and last - first == r["length"] and last <= frames):
                problems.append(f"episode {e}: {key} spans {t0}..{t1} s of a {frames}-frame file, "
                                f"its length is {r['length']}")
            if frames != r["length"]:
                problems.append(f"episode {e}: {path} has {frames} frames, the episode {r['length']}")
            decoded += frames
    report["video_frames"] = decoded


def check_openpi_images(t, src, row, e, picks, problems, report):
    """The export's `ee_image` of episode e against the source's frames at the picks (frame
    indices in the source episode): the same PNG bytes for an image dataset; for a video
    dataset, the pixels imageio-ffmpeg decodes from the source MP4 at those timestamps."""
    import io

    from PIL import Image

    key = "observation.images.ee_camera"
    ft = src["info"]["features"].get(key)
    exported = [item["bytes"] for item in t.column("ee_image").to_pylist()]
    if ft is None:
        problems.append(f"openpi episode {e}: ee_image without a source {key}")
        return
    if ft["dtype"] == "image":
        a = row["dataset_from_index"]
        rows = src["order"][a + picks]
        sources = [item["bytes"] for tab in src["tables"] for item in tab.column(key).to_pylist()]
        if exported != [sources[i] for i in rows]:
            problems.append(f"openpi episode {e}: ee_image is not the source's image at every pick")
        report["openpi_images"] = report.get("openpi_images", 0) + len(exported)
        return
    import imageio_ffmpeg

    info = src["info"]
    fps = info["fps"]
    path = os.path.join(src["root"], info["video_path"].format(
        video_key=key, chunk_index=row[f"videos/{key}/chunk_index"],
        file_index=row[f"videos/{key}/file_index"]))
    first = round(row[f"videos/{key}/from_timestamp"] * fps)
    wanted = {first + int(k): i for i, k in enumerate(picks)}
    h, w, _ = ft["shape"]
    reader = imageio_ffmpeg.read_frames(path)
    next(reader)
    decoded = {}
    for n, frame in enumerate(reader):
        if n in wanted:
            decoded[wanted[n]] = np.frombuffer(frame, dtype=np.uint8).reshape(h, w, 3)
    if len(decoded) != len(picks):
        problems.append(f"openpi episode {e}: {path} has {len(decoded)} of the {len(picks)} picked frames")
        return
    for i, png in enumerate(exported):
        img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
        if not np.array_equal(img, decoded[i]):
            diff = np.abs(img.astype(int) - decoded[i].astype(int)).max()
            problems.append(f"openpi episode {e}: ee_image {i} differs from {path}'s frame "
                            f"{first + int(picks[i])} (max |difference| {diff})")
            return
    report["openpi_images"] = report.get("openpi_images", 0) + len(exported)


def check_openpi(out, src, problems, report):
    info = json.load(open(os.path.join(out, "meta/info.json")))
    if info.get("codebase_version") != "v2.1":
        problems.append(f"openpi info.json: codebase_version {info.get('codebase_version')!r}")
    src_fps = src["info"]["fps"]
    stride = src_fps // info["fps"]
    keys = src["info"]["ambench"]["state_keys"]
    offsets, o = {}, 0
    for k in keys:
        d = STATE_DIMS.get(k, src["info"]["features"]["action"]["shape"][0] - 8)
        offsets[k] = (o, d)
        o += d
    episodes = [json.loads(line) for line in open(os.path.join(out, "meta/episodes.jsonl"))]
    frames = 0
    for r, e in zip(src["episodes"], episodes):
        a, length = r["dataset_from_index"], r["length"]
        picks = a + stride * np.arange(length // stride)
        path = os.path.join(out, f"data/chunk-{e['episode_index'] // 1000:03d}/episode_{e['episode_index']:06d}.parquet")
        t = pq.read_table(path)
        frames += t.num_rows
        if t.num_rows != length // stride or e["length"] != t.num_rows:
            problems.append(f"openpi episode {e['episode_index']}: {t.num_rows} frames, expected {length // stride}")
            continue
        actions = t.column("actions").combine_chunks().flatten().to_numpy().reshape(t.num_rows, -1)
        if not np.array_equal(actions, src["action"][picks]):
            problems.append(f"openpi episode {e['episode_index']}: actions are not every {stride}th source action")
        for k in ("ee_pos", "ee_quat", "gripper_width", "base_pos", "base_quat", "arm_joint_pos"):
            if k not in t.column_names:
                continue
            off, d = offsets[k]
            c = t.column(k).combine_chunks()
            v = (c.flatten().to_numpy() if d > 1 else c.to_numpy()).reshape(t.num_rows, d)
            if not np.array_equal(v, src["state"][picks, off:off + d]):
                problems.append(f"openpi episode {e['episode_index']}: {k} is not every {stride}th source state")
        if "ee_image" in t.column_names:
            check_openpi_images(t, src, r, e["episode_index"], picks - a, problems, report)
        if not np.array_equal(t.column("frame_index").to_numpy(), np.arange(t.num_rows)):
            problems.append(f"openpi episode {e['episode_index']}: frame_index")
        ts = t.column("timestamp").to_numpy()
        if not np.array_equal(ts, (np.arange(t.num_rows) / info["fps"]).astype(np.float32)):
            problems.append(f"openpi episode {e['episode_index']}: timestamp != frame_index / fps")
    report["openpi_frames"] = frames
    if frames != info["total_frames"]:
        problems.append(f"openpi: {frames} frames, info.json says {info['total_frames']}")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dir")
    p.add_argument("--openpi", help="an export-openpi output of DIR to check against it")
    p.add_argument("--json", action="store_true")
    a = p.parse_args()
    problems, report = [], {}
    try:
        src = check_dataset(a.dir, problems, report)
        if a.openpi:
            check_openpi(a.openpi, src, problems, report)
    except (OSError, KeyError, ValueError, TypeError, IndexError) as e:
        problems.append(f"cannot read: {type(e).__name__}: {e}")
    report["problems"] = problems
    if a.json:
        print(json.dumps(report))
    else:
        for line in problems:
            print(line)
        if not problems:
            print(f"ok: {report.get('episodes')} episodes, {report.get('frames')} frames"
                  + (f", openpi {report.get('openpi_frames')} frames" if a.openpi else ""))
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
