#!/usr/bin/env python3
"""Why did a benchmark's rollouts fail? Reads the output folder of
`amstack bench ... --out DIR` (results.json and each failing rollout's MCAP, with the PyPI
`mcap` reader) and measures, per failing rollout:

- the phase: the first success criterion the rollout never reached (or "success" for
  single-criterion tasks);
- tracking: how far the end-effector link stayed from its reference, |ee - ee_ref| (the
  script's target, or the IK's reachable version of it), 95th percentile and max, m;
- tilt: the base's largest tilt from upright, deg, and the results' saturation rate;
- the termination (timeout, diverged...).

Each failing rollout gets one reason, the first that applies:
  diverged      the twin's state blew up;
  tilt/thrust   the base tilts more than 30 deg or the rotors saturate more than 50 % of ticks;
  tracking      the EE misses its reference by more than 5 cm (95th percentile): reach,
                payload or the controller's authority;
  on-reference  the EE flies its reference (p95 <= 5 cm) yet the phase's contact, grasp or
                release does not happen as it should: e.g. the vehicle's tool tip is not where
                the script's numbers (the EE-link targets every vehicle is given) put the
                FA-Hexa's, or the object slips, or the throw misses.

    failure_reasons.py DIR [DIR...] [--json OUT]

Prints a markdown table per folder: task, failing rollouts, their reasons (count), median
figures. Exit 0; 2 on bad usage or an unreadable results.json (a rollout whose MCAP cannot be
read is reported as "no log", with a line on stderr).
"""

import argparse
import collections
import glob
import json
import math
import os
import statistics
import sys

from mcap.reader import make_reader

TILT_LIMIT_DEG = 30.0
SATURATION_LIMIT = 0.5
TRACKING_LIMIT_M = 0.05


def tilt_deg(q):
    """Angle between the body z axis and world z, from a (w, x, y, z) quaternion."""
    w, x, y, z = q
    zz = 1.0 - 2.0 * (x * x + y * y)
    return math.degrees(math.acos(max(-1.0, min(1.0, zz))))


def measure(path):
    ee, ref, tilt, order = {}, {}, [], None
    with open(path, "rb") as fh:
        for sch, ch, msg in make_reader(fh).iter_messages(
            topics=["/ee/pose", "/ee/reference", "/base/state", "/task/state"]
        ):
            if sch.encoding != "jsonschema":
                continue
            if ch.topic == "/task/state":
                if order is None:
                    order = [c["name"] for c in json.loads(msg.data)["criteria"]]
                continue
            d = json.loads(msg.data)
            if ch.topic == "/base/state":
                tilt.append(tilt_deg(d["orientation_wxyz"]))
            else:
                p = d["pose"]["position"]
                (ee if ch.topic == "/ee/pose" else ref)[msg.log_time] = (p["x"], p["y"], p["z"])
    errors = sorted(math.dist(ee[t], ref[t]) for t in ee if t in ref)
    if not errors:
        return None
    p95 = errors[min(len(errors) - 1, int(0.95 * len(errors)))]
    return {"ee_error_p95_m": p95, "ee_error_max_m": errors[-1], "max_tilt_deg": max(tilt or [0.0]),
            "criteria_order": order or []}


def reason(r, m):
    if r["termination"] == "diverged":
        return "diverged"
    if m is None:
        return "no log"
    if m["max_tilt_deg"] > TILT_LIMIT_DEG or (r.get("saturation_rate") or 0.0) > SATURATION_LIMIT:
        return "tilt/thrust"
    if m["ee_error_p95_m"] > TRACKING_LIMIT_M:
        return "tracking"
    return "on-reference"


def phase(r, m):
    """The first criterion, in the task's order (the log's), the rollout never reached."""
    crit = r.get("criteria") or {}
    for name in (m or {}).get("criteria_order") or sorted(crit):
        if not crit.get(name, True):
            return name
    return "success" if not crit else "all criteria, not at once"


def locate(mcap, folder):
    """The rollout's log: the path results.json records (relative to where `bench` ran), else
    the same path under the folder's `rollouts/` (the folder moved, or `bench` ran elsewhere)."""
    if not mcap:
        return None
    if os.path.exists(mcap):
        return mcap
    parts = mcap.replace("\\", "/").split("/")
    if "rollouts" in parts:
        moved = os.path.join(folder, *parts[parts.index("rollouts"):])
        if os.path.exists(moved):
            return moved
    return None


def analyse(folder):
    path = os.path.join(folder, "results.json")
    try:
        with open(path) as fh:
            results = json.load(fh)
    except (OSError, ValueError) as e:
        print(f"failure_reasons: {path}: {e}", file=sys.stderr)
        sys.exit(2)
    cfg = results.get("config", {})
    rows = []
    for task, t in sorted(results["tasks"].items()):
        failing = [r for r in t["per_rollout"] if not r["success"]]
        if not failing:
            continue
        per = []
        for r in failing:
            mcap = locate(r.get("mcap"), folder)
            m = None
            if mcap:
                try:
                    m = measure(mcap)
                except Exception as e:  # a truncated or foreign file: say so, go on
                    print(f"failure_reasons: {mcap}: unreadable ({e}); reason 'no log'",
                          file=sys.stderr)
            per.append({"index": r["index"], "phase": phase(r, m), "reason": reason(r, m),
                        "saturation_rate": r.get("saturation_rate"), **(m or {})})
        rows.append({"task": task, "rollouts": len(t["per_rollout"]), "failing": per})
    return {"folder": folder, "platform": cfg.get("platform"), "controller": cfg.get("controller"),
            "disturbances": cfg.get("disturbances"), "tasks": rows}


def med(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else float("nan")


def print_table(a):
    print(f"\n{a['folder']}: {a['platform']}, {a['controller']}, disturbances {a['disturbances']}")
    print("| task | failing | reasons | first unmet criterion | EE error p95 / max (m, median) "
          "| max tilt (deg, median) | saturation (median) |")
    print("|---|---|---|---|---|---|---|")
    for row in a["tasks"]:
        f = row["failing"]
        reasons = collections.Counter(x["reason"] for x in f)
        phases = collections.Counter(x["phase"] for x in f)
        print(f"| {row['task']} | {len(f)}/{row['rollouts']} | "
              + ", ".join(f"{k} {v}" for k, v in reasons.most_common()) + " | "
              + ", ".join(f"{k} {v}" for k, v in phases.most_common()) + " | "
              + f"{med([x.get('ee_error_p95_m') for x in f]):.3f} / "
              + f"{med([x.get('ee_error_max_m') for x in f]):.3f} | "
              + f"{med([x.get('max_tilt_deg') for x in f]):.1f} | "
              + f"{100 * med([x.get('saturation_rate') for x in f]):.1f} % |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", help="output folders of `amstack bench --out`")
    ap.add_argument("--json", help="also write the per-rollout measurements here")
    args = ap.parse_args()
    out = [analyse(f) for f in args.folders]
    for a in out:
        print_table(a)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
