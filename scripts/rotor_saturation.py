#!/usr/bin/env python3
"""When and which rotors saturate in an amstack flight log (independent of amstack's reader).

Usage: rotor_saturation.py LOG.mcap [LOG.mcap ...] --limits T_MIN T_MAX [--tol N] [--json]

Reads `/rotors` (realised thrust per rotor, N; logged one control period after the tick) with
the PyPI `mcap` package and prints, per log and per rotor: the first time the realised thrust
is at the upper limit (within --tol, default 1e-5 N) and at the lower limit, the share of
ticks at a limit, and the largest realised thrust. Also the first time `/control/wrench` has a
non-zero unallocated wrench (the allocator could not deliver the request). Markdown table,
or with --json one JSON document (the cross-check of `amstack experiment wrench-limit`, whose
summary is computed in Rust). Run with the venv of scripts/setup-python.sh.
"""

import argparse
import json
import sys

from mcap.stream_reader import StreamReader
from mcap.records import Channel, Message


def read(path, topics):
    channels, out = {}, {t: [] for t in topics}
    with open(path, "rb") as f:
        for record in StreamReader(f, skip_magic=False).records:
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                topic = channels.get(record.channel_id)
                if topic in out:
                    out[topic].append((record.log_time * 1e-9, json.loads(record.data)))
    return out


def fmt(t):
    return "never" if t is None else f"{t:.3f}"


def summarise(path, lo, hi, tol):
    """The per-rotor summary of one log, or None without /rotors messages."""
    data = read(path, ["/rotors", "/control/wrench"])
    rotors = data["/rotors"]
    if not rotors:
        return None
    out = []
    for i in range(len(rotors[0][1]["realised_n"])):
        first_hi = first_lo = None
        at_limit, peak = 0, float("-inf")
        for t, m in rotors:
            x = m["realised_n"][i]
            peak = max(peak, x)
            if x >= hi - tol:
                first_hi = t if first_hi is None else first_hi
                at_limit += 1
            elif x <= lo + tol:
                first_lo = t if first_lo is None else first_lo
                at_limit += 1
        out.append({"rotor": i, "first_at_max_s": first_hi, "first_at_min_s": first_lo,
                    "share_at_limit": at_limit / len(rotors), "max_thrust_n": peak})
    first = next((t for t, m in data["/control/wrench"]
                  if any(abs(v) > 1e-9 for v in m["unallocated_force_n"] + m["unallocated_torque_nm"])), None)
    return {"path": path, "ticks": len(rotors), "rotors": out, "first_unallocated_s": first}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("logs", nargs="+")
    p.add_argument("--limits", nargs=2, type=float, required=True, metavar=("T_MIN", "T_MAX"))
    p.add_argument("--tol", type=float, default=1e-5)
    p.add_argument("--json", action="store_true", help="print one JSON document")
    a = p.parse_args()
    lo, hi = a.limits
    logs = []
    for path in a.logs:
        summary = summarise(path, lo, hi, a.tol)
        if summary is None:
            print(f"rotor_saturation: {path}: no /rotors messages", file=sys.stderr)
            return 1
        logs.append(summary)
    if a.json:
        print(json.dumps({"limits_n": [lo, hi], "tolerance_n": a.tol, "logs": logs}))
        return 0
    print("| log | rotor | first at T_max (s) | first at T_min (s) | ticks at a limit (%) | max thrust (N) |")
    print("|---|---|---|---|---|---|")
    for log in logs:
        for r in log["rotors"]:
            print(f"| {log['path']} | {r['rotor']} | {fmt(r['first_at_max_s'])} | {fmt(r['first_at_min_s'])} "
                  f"| {100.0 * r['share_at_limit']:.1f} | {r['max_thrust_n']:.2f} |")
    print()
    for log in logs:
        print(f"{log['path']}: first unallocated wrench at t = {fmt(log['first_unallocated_s'])} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
