#!/usr/bin/env python3
"""When and which rotors saturate in an amstack flight log (independent of amstack's reader).

Usage: rotor_saturation.py LOG.mcap [LOG.mcap ...] --limits T_MIN T_MAX [--tol N]

Reads `/rotors` (realised thrust per rotor, N; logged one control period after the tick) with
the PyPI `mcap` package and prints, per log and per rotor: the first time the realised thrust
is at the upper limit (within --tol, default 1e-5 N) and at the lower limit, the share of
ticks at a limit, and the largest realised thrust. Also the first time `/control/wrench` has a
non-zero unallocated wrench (the allocator could not deliver the request). Markdown table.
Run with the venv of scripts/setup-python.sh.
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


def main():
    p = argparse.ArgumentParser()
    p.add_argument("logs", nargs="+")
    p.add_argument("--limits", nargs=2, type=float, required=True, metavar=("T_MIN", "T_MAX"))
    p.add_argument("--tol", type=float, default=1e-5)
    a = p.parse_args()
    lo, hi = a.limits
    print("| log | rotor | first at T_max (s) | first at T_min (s) | ticks at a limit (%) | max thrust (N) |")
    print("|---|---|---|---|---|---|")
    unallocated = []
    for path in a.logs:
        data = read(path, ["/rotors", "/control/wrench"])
        rotors = data["/rotors"]
        if not rotors:
            print(f"rotor_saturation: {path}: no /rotors messages", file=sys.stderr)
            return 1
        n = len(rotors[0][1]["realised_n"])
        for i in range(n):
            first_hi = first_lo = None
            at_limit, peak = 0, float("-inf")
            for t, m in rotors:
                x = m["realised_n"][i]
                peak = max(peak, x)
                if x >= hi - a.tol:
                    first_hi = t if first_hi is None else first_hi
                    at_limit += 1
                elif x <= lo + a.tol:
                    first_lo = t if first_lo is None else first_lo
                    at_limit += 1
            share = 100.0 * at_limit / len(rotors)
            print(f"| {path} | {i} | {fmt(first_hi)} | {fmt(first_lo)} | {share:.1f} | {peak:.2f} |")
        first = next((t for t, m in data["/control/wrench"]
                      if any(abs(v) > 1e-9 for v in m["unallocated_force_n"] + m["unallocated_torque_nm"])), None)
        unallocated.append((path, first))
    print()
    for path, first in unallocated:
        print(f"{path}: first unallocated wrench at t = {fmt(first)} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
