#!/usr/bin/env python3
"""Split a benchmark run's tilt use and rotor saturation by phase and by who flew each tick.

Reads every rollout MCAP of one task (`amstack bench ... --controller mpc --out DIR` writes
DIR/rollouts/<task>/rollout-NNN.mcap) with the PyPI `mcap` reader and, per tick:
- tilt = sqrt(roll^2 + pitch^2) of `/base/state` (the benchmark's tilt use is its maximum);
- saturated = any realised thrust of `/rotors` at or below 1e-5 N or at or above the limit
  minus 1e-5 N (the benchmark's indicator; `--thrust-max`, default the FA-Hexa's 23 N);
- phase = `contact` from the first tick the task reports `holding` (a grasp engaged) or a task
  object moved (`slider_pos`, `valve_angle`, `button_pos` observations), `free` before;
- mode = `/mpc/status.mode` (mpc, hold, ik_pid), `-` for a flight without the MPC.
The last tick of each rollout is dropped, as the benchmark's metrics drop it.

usage: mpc_phases.py DIR/rollouts/<task> [--json FILE] [--thrust-max N]
Prints one line per rollout (success, max tilt and where, first contact, first tick not flown
by the MPC, first tick with tilt > 0.05 rad) and the totals per phase and per phase x mode.
Exit 2 on a bad argument or an unreadable directory.
"""
import argparse
import glob
import json
import math
import os
import sys
from collections import defaultdict

OBJECT_OBSERVATIONS = ("slider_pos", "valve_angle", "button_pos")
TOPICS = ["/mpc/status", "/base/state", "/rotors", "/task/state"]


def tilt_rad(wxyz):
    w, x, y, z = wxyz
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    return math.hypot(roll, pitch)


def rollout_ticks(path, thrust_max):
    from mcap.reader import make_reader

    per_topic = defaultdict(list)
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=TOPICS):
            per_topic[channel.topic].append(json.loads(message.data))
    n = len(per_topic["/base/state"])
    ticks, start, contact, success = [], None, False, False
    for k in range(n):
        task = per_topic["/task/state"][k] if k < len(per_topic["/task/state"]) else {}
        success = success or bool(task.get("success"))
        observed = {o["name"]: o["values"] for o in task.get("observation", [])}
        for name in OBJECT_OBSERVATIONS:
            if name in observed:
                if start is None:
                    start = list(observed[name])
                if any(abs(a - b) > 1e-4 for a, b in zip(observed[name], start)):
                    contact = True
        contact = contact or bool(task.get("holding"))
        rotors = per_topic["/rotors"][k]["realised_n"] if k < len(per_topic["/rotors"]) else []
        mpc = per_topic["/mpc/status"][k] if k < len(per_topic["/mpc/status"]) else {}
        ticks.append(
            {
                "tick": k,
                "tilt": tilt_rad(per_topic["/base/state"][k]["orientation_wxyz"]),
                "saturated": any(t <= 1e-5 or t >= thrust_max - 1e-5 for t in rotors),
                "phase": "contact" if contact else "free",
                "mode": mpc.get("mode", "-"),
            }
        )
    return ticks[:-1] if len(ticks) > 1 else ticks, success


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("task_dir")
    parser.add_argument("--json", dest="json_path")
    parser.add_argument("--thrust-max", type=float, default=23.0)
    args = parser.parse_args()
    paths = sorted(glob.glob(os.path.join(args.task_dir, "*.mcap")))
    if not paths:
        print(f"mpc_phases: no rollout-*.mcap in {args.task_dir}", file=sys.stderr)
        sys.exit(2)
    groups = defaultdict(lambda: {"ticks": 0, "saturated": 0, "tilts": []})
    rollouts = []
    for path in paths:
        ticks, success = rollout_ticks(path, args.thrust_max)
        worst = max(ticks, key=lambda t: t["tilt"])
        first = lambda pred: next((t["tick"] for t in ticks if pred(t)), None)  # noqa: E731
        rollouts.append(
            {
                "rollout": os.path.basename(path),
                "success": success,
                "max_tilt_rad": worst["tilt"],
                "max_tilt_phase": worst["phase"],
                "max_tilt_mode": worst["mode"],
                "saturation_rate": sum(t["saturated"] for t in ticks) / len(ticks),
                "first_contact_tick": first(lambda t: t["phase"] == "contact"),
                "first_not_mpc_tick": first(lambda t: t["mode"] not in ("mpc", "-")),
                "first_tilt_over_0_05_tick": first(lambda t: t["tilt"] > 0.05),
            }
        )
        for t in ticks:
            for key in ("all", t["phase"], f"{t['phase']}/{t['mode']}"):
                g = groups[key]
                g["ticks"] += 1
                g["saturated"] += t["saturated"]
                g["tilts"].append(t["tilt"])
    summary = {}
    for key in sorted(groups):
        g = groups[key]
        tilts = sorted(g["tilts"])
        summary[key] = {
            "ticks": g["ticks"],
            "saturation_rate": g["saturated"] / g["ticks"],
            "tilt_mean_rad": sum(tilts) / len(tilts),
            "tilt_p99_rad": tilts[int(0.99 * (len(tilts) - 1))],
            "tilt_max_rad": tilts[-1],
        }
    for r in rollouts:
        print(
            f"{r['rollout']}: success {r['success']}, max tilt {r['max_tilt_rad']:.3f} rad "
            f"({r['max_tilt_phase']}, {r['max_tilt_mode']}), saturation "
            f"{100 * r['saturation_rate']:.1f} %, first contact {r['first_contact_tick']}, "
            f"first tick not flown by the MPC {r['first_not_mpc_tick']}, first tilt > 0.05 rad "
            f"{r['first_tilt_over_0_05_tick']}"
        )
    print(f"{'phase/mode':16s} {'ticks':>6s} {'sat %':>6s} {'tilt mean':>9s} {'p99':>6s} {'max':>6s}")
    for key, s in summary.items():
        print(
            f"{key:16s} {s['ticks']:6d} {100 * s['saturation_rate']:6.1f} "
            f"{s['tilt_mean_rad']:9.4f} {s['tilt_p99_rad']:6.3f} {s['tilt_max_rad']:6.3f}"
        )
    if args.json_path:
        with open(args.json_path + ".tmp", "w") as f:
            json.dump({"rollouts": rollouts, "summary": summary}, f, indent=1, sort_keys=True)
        os.replace(args.json_path + ".tmp", args.json_path)


if __name__ == "__main__":
    main()
