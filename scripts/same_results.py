#!/usr/bin/env python3
"""Compares two folders of amstack outputs written by the same commands with two builds.

Usage: same_results.py BASE_DIR HEAD_DIR [--ignore-field TOPIC:FIELD ...]

Every file under BASE_DIR must exist under HEAD_DIR (and the reverse):
- `*.json` (results): equal after dropping wall-clock figures (`timing`, `wall_time_s`,
  `ticks_per_second`, `seconds_per_rollout`, `rollouts_per_minute`, `env_steps_per_second`);
- `*.mcap` (flight logs), read with the PyPI `mcap` package (not amstack's code): the same
  channels with the same schemas, and per channel the same messages (log time, publish time and
  payload bytes), except on the channels that carry wall-clock readings by design
  (`/mavlink/raw`, `/autopilot/state`: skipped) and the fields that read it
  (`/mpc/status` `solve_time_ms`). Metadata
  records must be equal. With --ignore-field /rotors:applied_n the named JSON field of that
  channel's payloads is dropped before comparing (for a deliberate fix of a logged field).

Prints one line per file and a closing `N passed, N failed` line; exit 1 on any difference.
"""

import argparse
import json
import os
import sys

from mcap.reader import make_reader

WALL_CLOCK_KEYS = {"timing", "wall_time_s", "ticks_per_second", "seconds_per_rollout",
                   "rollouts_per_minute", "env_steps_per_second", "round_trip", "timing_json",
                   # the address of a link (a free UDP port chosen per run)
                   "link"}
# Payload fields that read the wall clock (the MPC's solve time by the caller's clock).
WALL_CLOCK_FIELDS = {"/mpc/status": ["solve_time_ms"]}
WALL_CLOCK_TOPICS = {"/mavlink/raw", "/autopilot/state"}


def strip(value):
    if isinstance(value, dict):
        return {k: strip(v) for k, v in value.items() if k not in WALL_CLOCK_KEYS}
    if isinstance(value, list):
        return [strip(v) for v in value]
    return value


def first_difference(a, b, path="$"):
    if type(a) is not type(b):
        return f"{path}: {a!r} vs {b!r}"
    if isinstance(a, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                return f"{path}.{k}: only in {'head' if k in b else 'base'}"
            d = first_difference(a[k], b[k], f"{path}.{k}")
            if d:
                return d
        return None
    if isinstance(a, list):
        if len(a) != len(b):
            return f"{path}: {len(a)} vs {len(b)} items"
        for i, (x, y) in enumerate(zip(a, b)):
            d = first_difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    return None if a == b else f"{path}: {a!r} vs {b!r}"


def read_mcap(path):
    channels, metadata = {}, []
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            key = (channel.topic, schema.name if schema else None, channel.message_encoding)
            channels.setdefault(key, []).append(
                (message.log_time, message.publish_time, bytes(message.data)))
        f.seek(0)
        reader = make_reader(f)
        for record in reader.iter_metadata():
            metadata.append((record.name, dict(record.metadata)))
    return channels, metadata


def drop_fields(payload, fields):
    if not fields:
        return payload
    value = json.loads(payload)
    for f in fields:
        value.pop(f, None)
    return json.dumps(value, sort_keys=True).encode()


def compare_mcap(base, head, ignore):
    a, ma = read_mcap(base)
    b, mb = read_mcap(head)
    if ma != mb:
        return "metadata records differ"
    if set(a) != set(b):
        return f"channels differ: only base {sorted(set(a) - set(b))}, only head {sorted(set(b) - set(a))}"
    for key in sorted(a):
        topic = key[0]
        x, y = a[key], b[key]
        if topic in WALL_CLOCK_TOPICS:
            continue  # heartbeats and frames on the wall clock: their number varies too
        if len(x) != len(y):
            return f"{topic}: {len(x)} vs {len(y)} messages"
        fields = ignore.get(topic, []) + WALL_CLOCK_FIELDS.get(topic, [])
        for i, (p, q) in enumerate(zip(x, y)):
            if p[:2] != q[:2] or drop_fields(p[2], fields) != drop_fields(q[2], fields):
                return f"{topic} message {i} (log time {p[0]} ns) differs"
    return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("base")
    ap.add_argument("head")
    ap.add_argument("--ignore-field", action="append", default=[])
    args = ap.parse_args()
    ignore = {}
    for spec in args.ignore_field:
        topic, _, field = spec.partition(":")
        ignore.setdefault(topic, []).append(field)

    def files(root):
        out = set()
        for d, _, names in os.walk(root):
            for n in names:
                if n.endswith((".json", ".mcap")):
                    out.add(os.path.relpath(os.path.join(d, n), root))
        return out

    fa, fb = files(args.base), files(args.head)
    passed = failed = 0
    for rel in sorted(fa | fb):
        if rel not in fa or rel not in fb:
            print(f"DIFF {rel}: only in {'head' if rel in fb else 'base'}")
            failed += 1
            continue
        pa, pb = os.path.join(args.base, rel), os.path.join(args.head, rel)
        if rel.endswith(".json"):
            with open(pa) as f:
                ja = strip(json.load(f))
            with open(pb) as f:
                jb = strip(json.load(f))
            why = first_difference(ja, jb)
        else:
            why = compare_mcap(pa, pb, ignore)
        if why:
            print(f"DIFF {rel}: {why}")
            failed += 1
        else:
            print(f"same {rel}")
            passed += 1
    print(f"{passed} passed, {failed} failed")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
