#!/usr/bin/env python3
"""Where each Toss Ball rollout's ball was let go and where it came down, from the flight logs.

Usage: toss_landing.py OUT_DIR   (the folder of `amstack bench --task toss-ball --out OUT_DIR`)

Reads every `OUT_DIR/rollouts/toss-ball/*.mcap` with the PyPI `mcap` package (not amstack's
code) and prints, per rollout: the container's x, the step and the ball's world velocity
where the gripper stops holding it (`/task/state` `holding` false), the ball's x where it first
comes down through the container's rim height (0.17 m) minus the container's x, and how far
the base (`/base/state`) is then behind the container (the success needs ≥ 0.7 m, AMBENCH_SPEC
§4.11). A closing line gives the ranges. Exit 2 when the folder holds no Toss Ball log.
"""

import glob
import json
import math
import sys

from mcap.reader import make_reader

RIM_HEIGHT_M = 0.17


def rollout(path):
    target_x = release = landing = behind = None
    base_x = math.nan
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(
            topics=["/task/state", "/base/state"]
        ):
            d = json.loads(message.data)
            if channel.topic == "/base/state":
                base_x = d["position_m"][0]
                continue
            o = {x["name"]: x["values"] for x in d["observation"]}
            if target_x is None:
                target_x = o["target_pos"][0]
            if release is None and not d["holding"]:
                release = (d["step"], o["ball_lin_vel"])
            if release and landing is None and o["ball_pos"][2] < RIM_HEIGHT_M:
                landing = o["ball_pos"][0] - target_x
                behind = target_x - base_x
    return target_x, release, landing, behind


def main():
    if len(sys.argv) != 2:
        print("usage: toss_landing.py OUT_DIR", file=sys.stderr)
        return 2
    paths = sorted(glob.glob(f"{sys.argv[1]}/rollouts/toss-ball/*.mcap"))
    if not paths:
        print(f"toss_landing: no rollouts/toss-ball/*.mcap under {sys.argv[1]}", file=sys.stderr)
        return 2
    rows = []
    for path in paths:
        target_x, release, landing, behind = rollout(path)
        name = path.rsplit("/", 1)[-1]
        if release is None:
            print(f"{name}: container x {target_x:.3f}, never let go")
            continue
        step, v = release
        land = "never came down" if landing is None else f"lands {landing:+.3f}"
        print(
            f"{name}: container x {target_x:.3f}, let go at step {step} at "
            f"({v[0]:.2f}, {v[1]:.2f}, {v[2]:.2f}) m/s, {land}"
            + ("" if behind is None else f", base {behind:.2f} m behind")
        )
        rows.append((v, landing, behind))
    if rows:
        def span(values):
            values = [x for x in values if x is not None]
            return f"{min(values):+.2f}…{max(values):+.2f}" if values else "none"

        print(
            f"{len(rows)} of {len(paths)} let go: forward {span(r[0][0] for r in rows)} m/s, "
            f"up {span(r[0][2] for r in rows)} m/s, lands {span(r[1] for r in rows)} m past the "
            f"centre, base {span(r[2] for r in rows)} m behind it"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
