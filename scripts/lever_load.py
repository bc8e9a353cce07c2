#!/usr/bin/env python3
"""What limits Pull Lever? Reads the rollout MCAPs of
`amstack bench --task pull-lever ... --out DIR` (PyPI `mcap` reader) and measures, per
rollout, over the hold (the ticks the grasp holds the lever, `/task/state` `holding`):

- q_max: the lever's largest angle in the rollout (deg; success at 40);
- q_end: its angle at the end of the hold (deg);
- torque: the torque the lever took, from its angle alone as its drive sees it,
  c * dq/dt + k * q, mean and max over the hold, N·m. The drive is an acceleration drive
  (README, departures): the spec's 100 /s and 20 /s² (AMBENCH_SPEC §4.8) times the arm's
  inertia about the pivot, 2.8167e-3 kg·m², plus rapier's default 0.1 N·m·s/rad on a free
  angular multibody joint: c = 0.38167 N·m·s/rad, k = 0.056333 N·m/rad (the arm's own
  inertial torque is left out);
- pitch_end: the base's pitch at the end of the hold (deg): with the bar welded in the fingers
  and the arm at the IK's joint targets, the lever turns only as far as the vehicle pitches;
- pitch_gap: the largest |lever angle - base pitch| over the hold (deg): near 0 when the lever
  turns only as the whole vehicle pitches;
- pushed_back: how far the base went back (world -x) during the hold, m.

    lever_load.py DIR [DIR...] [--json OUT]

Prints one row per rollout and a summary per folder. Exit 0; 2 on bad usage, a folder without
pull-lever rollouts, or an MCAP that cannot be read.
"""

import argparse
import glob
import json
import math
import os
import sys

from mcap.reader import make_reader

ARM_INERTIA_KGM2 = 0.2 * (0.205 ** 2 / 3.0 + 0.03 ** 2 / 12.0)
STIFFNESS = 20.0 * ARM_INERTIA_KGM2
DAMPING = 100.0 * ARM_INERTIA_KGM2 + 0.1
CONTROL_DT_S = 1.0 / 120.0


def pitch_deg(q):
    w, x, y, z = q
    return math.degrees(math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x)))))


def measure(path):
    lever, holding, pitch, base_x = [], [], [], []
    with open(path, "rb") as fh:
        for sch, ch, msg in make_reader(fh).iter_messages(topics=["/task/state", "/base/state"]):
            if sch.encoding != "jsonschema":
                continue
            m = json.loads(msg.data)
            if ch.topic == "/task/state":
                obs = {o["name"]: o["values"] for o in m["observation"]}
                lever.append(obs["lever_joint_pos"][0])
                holding.append(bool(m.get("holding")))
            else:
                pitch.append(pitch_deg(m["orientation_wxyz"]))
                base_x.append(m["position_m"][0])
    if not lever:
        raise ValueError("no /task/state with lever_joint_pos")
    row = {"rollout": os.path.basename(path), "q_max_deg": math.degrees(max(lever))}
    held = [k for k, h in enumerate(holding) if h]
    if len(held) < 3:
        row.update(held=None)
        return row
    a, b = held[0], held[-1]
    torque = [
        DAMPING * (lever[k + 1] - lever[k - 1]) / (2.0 * CONTROL_DT_S) + STIFFNESS * lever[k]
        for k in range(a + 1, b)
    ]
    end = min(b, len(pitch) - 1)
    gap = max(abs(math.degrees(lever[k]) - pitch[k]) for k in range(a, end + 1))
    row.update(
        held=[a, b],
        q_end_deg=math.degrees(lever[b]),
        torque_mean_nm=sum(torque) / len(torque),
        torque_max_nm=max(torque),
        pitch_end_deg=pitch[end],
        pitch_gap_deg=gap,
        pushed_back_m=base_x[min(a, end)] - min(base_x[min(a, end) : end + 1]),
    )
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dirs", nargs="+", help="output folders of amstack bench --task pull-lever")
    ap.add_argument("--json", help="write the rows as JSON here")
    args = ap.parse_args()
    out = {}
    for d in args.dirs:
        files = sorted(glob.glob(os.path.join(d, "rollouts", "pull-lever", "*.mcap")))
        if not files:
            print(f"lever_load.py: {d}: no rollouts/pull-lever/*.mcap", file=sys.stderr)
            return 2
        rows = []
        for f in files:
            try:
                rows.append(measure(f))
            except Exception as e:  # an unreadable or foreign log: name it, stop
                print(f"lever_load.py: {f}: {e}", file=sys.stderr)
                return 2
        out[d] = rows
        print(f"## {d}")
        print("| rollout | q_max (deg) | hold | q_end (deg) | torque mean / max (N·m) | base pitch (deg) | max abs(q - pitch) (deg) | base pushed back (m) |")
        print("|---|---|---|---|---|---|---|---|")
        for r in rows:
            if r.get("held") is None:
                print(f"| {r['rollout']} | {r['q_max_deg']:.1f} | never held | | | | | |")
                continue
            print(
                f"| {r['rollout']} | {r['q_max_deg']:.1f} | {r['held'][0]}-{r['held'][1]} | {r['q_end_deg']:.1f} | "
                f"{r['torque_mean_nm']:.1f} / {r['torque_max_nm']:.1f} | {r['pitch_end_deg']:.1f} | {r['pitch_gap_deg']:.2f} | {r['pushed_back_m']:.3f} |"
            )
        held = [r for r in rows if r.get("held")]
        qs = [r["q_max_deg"] for r in rows]
        line = f"{len(rows)} rollouts: q_max {min(qs):.1f}-{max(qs):.1f} deg"
        if held:
            mean = sum(r["torque_mean_nm"] for r in held) / len(held)
            gap = max(r["pitch_gap_deg"] for r in held)
            line += f"; mean lever torque over the hold {mean:.1f} N·m; abs(q - base pitch) <= {gap:.2f} deg ({len(held)} held)"
        print(line + "\n")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
