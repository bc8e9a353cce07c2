#!/usr/bin/env python3
"""Compares two `amstack bench --json` results of the same command (two builds, two configs).

Usage: bench_diff.py BEFORE.json AFTER.json [--top N]

Prints, per task, the successes before -> after (of the rollouts run), how many rollouts
ended `diverged` after, and how many rollouts are the same to the bit (equal success, steps
and tilt use); then the N largest relative moves of the per-task means over successful
rollouts of tilt use, normalised EE error and saturation rate. Exit 2 on unreadable input or
results of different tasks or rollout counts; exit 0 otherwise (the reading is the user's).
"""

import argparse
import json
import sys

METRICS = ("tilt_use_rad", "ee_error_normalised", "saturation_rate")


def fail(message):
    print(f"bench_diff: {message}", file=sys.stderr)
    sys.exit(2)


def load(path):
    try:
        with open(path, encoding="utf-8") as f:
            results = json.load(f)
        return results["tasks"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        fail(f"{path}: not an amstack bench result ({e})")


def mean(rollouts, key):
    values = [r[key] for r in rollouts if r.get("success") and r.get(key) is not None]
    return sum(values) / len(values) if values else None


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("before")
    parser.add_argument("after")
    parser.add_argument("--top", type=int, default=3, help="largest moves of a mean to print")
    args = parser.parse_args()
    before, after = load(args.before), load(args.after)
    if sorted(before) != sorted(after):
        fail(f"the tasks differ: {sorted(before)} vs {sorted(after)}")
    moves = []
    for task in sorted(before):
        rb, ra = before[task]["per_rollout"], after[task]["per_rollout"]
        if len(rb) != len(ra):
            fail(f"{task}: {len(rb)} rollouts before, {len(ra)} after")
        sb = sum(1 for r in rb if r["success"])
        sa = sum(1 for r in ra if r["success"])
        same = sum(
            1
            for x, y in zip(rb, ra)
            if (x["success"], x["executed_steps"], x.get("tilt_use_rad"))
            == (y["success"], y["executed_steps"], y.get("tilt_use_rad"))
        )
        diverged = sum(1 for r in ra if r.get("termination") == "diverged")
        mark = "" if sb == sa else f"  ({sa - sb:+d})"
        print(f"{task:24s} {sb:3d} -> {sa:3d} of {len(ra)}{mark}   same to the bit {same:3d}"
              f"   diverged after {diverged}")
        for key in METRICS:
            mb, ma = mean(rb, key), mean(ra, key)
            if mb is not None and ma is not None and abs(mb) > 1e-12:
                moves.append((abs(ma - mb) / abs(mb), task, key, mb, ma))
    moves.sort(reverse=True)
    for rel, task, key, mb, ma in moves[: args.top]:
        print(f"largest move: {task} {key} {mb:.4g} -> {ma:.4g} ({100 * rel:.1f} %)")


if __name__ == "__main__":
    main()
