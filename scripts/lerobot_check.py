#!/usr/bin/env python3
"""Loads an amstack dataset with lerobot's LeRobotDataset and compares frames with the files
(read with pyarrow): state, action, task, timestamp and images. Run by scripts/lerobot-check.sh."""

import glob
import io
import json
import os
import sys

import numpy as np
import pyarrow.parquet as pq
from PIL import Image

from lerobot.datasets.lerobot_dataset import LeRobotDataset


def main(root):
    root = os.path.abspath(root)
    info = json.load(open(os.path.join(root, "meta/info.json")))
    ds = LeRobotDataset("amstack/check", root=root)
    problems = []
    if len(ds) != info["total_frames"] or ds.num_episodes != info["total_episodes"]:
        problems.append(f"len {len(ds)}, episodes {ds.num_episodes}; info.json {info['total_frames']}, {info['total_episodes']}")
    table = pq.read_table(sorted(glob.glob(os.path.join(root, "data/*/*.parquet"))))
    index = table.column("index").to_numpy()
    tasks_t = pq.read_table(os.path.join(root, "meta/tasks.parquet")).to_pandas()
    image_keys = [k for k, f in info["features"].items() if f["dtype"] == "image"]
    n = len(ds)
    picks = sorted({0, 1, n // 3, n // 2, n - 2, n - 1})
    for i in picks:
        item = ds[i]
        row = int(np.nonzero(index == i)[0][0])
        state = np.array(table.column("observation.state")[row].as_py(), dtype=np.float32)
        action = np.array(table.column("action")[row].as_py(), dtype=np.float32)
        if not np.array_equal(item["observation.state"].numpy(), state):
            problems.append(f"frame {i}: observation.state differs")
        if not np.array_equal(item["action"].numpy(), action):
            problems.append(f"frame {i}: action differs")
        if float(item["timestamp"]) != table.column("timestamp")[row].as_py():
            problems.append(f"frame {i}: timestamp differs")
        task_index = table.column("task_index")[row].as_py()
        if item["task"] != tasks_t.index[tasks_t["task_index"] == task_index][0]:
            problems.append(f"frame {i}: task {item['task']!r}")
        for key in image_keys:
            png = table.column(key)[row].as_py()["bytes"]
            rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
            got = item[key].numpy()  # C, H, W float in [0, 1]
            want = rgb.transpose(2, 0, 1).astype(np.float32) / 255.0
            if got.shape != want.shape or np.abs(got - want).max() > 1e-6:
                problems.append(f"frame {i}: {key} differs (shape {got.shape} vs {want.shape})")
    stats = ds.meta.stats
    for key in ("observation.state", "action"):
        if key not in stats or stats[key]["mean"].shape != (info["features"][key]["shape"][0],):
            problems.append(f"meta.stats[{key}] missing or misshapen")
    print(json.dumps({
        "dataset": root,
        "lerobot_frames": len(ds),
        "episodes": ds.num_episodes,
        "fps": ds.fps,
        "features": sorted(ds.features),
        "frames_compared": picks,
        "image_keys": image_keys,
        "problems": problems,
    }))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
