#!/usr/bin/env python3
"""Converts an amstack MCAP log with Rerun (`rerun mcap convert`) and reads the .rrd back with
Rerun's own reader (`rerun.chunk.RrdReader`): what an independent viewer makes of the log.

Usage: rrd_check.py FILE.mcap [--rrd OUT.rrd] [--expect-transforms] [--expect-scene]
                   [--expect-images]

Prints one JSON object: per entity path (one per MCAP topic) the Rerun archetypes and
components it holds and its rows, and per topic whether Rerun understood it ("semantic": an
archetype other than its raw fallback `McapMessage` and the `McapChannel`/`McapSchema` records)
or kept only raw bytes.
--expect-transforms: /scene/tf must hold Transform3D rows (Rerun's Foxglove decoder turned
foxglove.FrameTransforms into transforms). --expect-scene: /scene/static, /scene/dynamic and
/scene/targets must hold decoded fields (the protobuf decoder's structured SceneUpdate: its
entities and primitives), not raw bytes. --expect-images: the log has camera channels, and
every /camera/<name>/image holds EncodedImage rows (an image, not raw bytes), every
/camera/<name>/calibration Pinhole rows and /camera/tf Transform3D rows. Exit 0 when the expectations hold, 1 otherwise.

Run it with the opt-in Rerun venv (scripts/setup-rerun.sh prints its python).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

try:
    from rerun.chunk import RrdReader
except ImportError:
    print("rrd_check: the Python 'rerun-sdk' package is missing: run scripts/setup-rerun.sh "
          "and use the python it prints", file=sys.stderr)
    sys.exit(2)

# What Rerun keeps of any channel it does not understand: the raw message and the channel's
# and schema's own records.
RAW = {"McapMessage", "McapChannel", "McapSchema"}


def column_archetype(field):
    meta = field.metadata or {}
    arch = meta.get(b"rerun:archetype") or meta.get(b"rerun.archetype")
    comp = meta.get(b"rerun:component") or meta.get(b"rerun.component")
    kind = meta.get(b"rerun:kind") or meta.get(b"rerun.kind")
    return (arch.decode() if arch else None, comp.decode() if comp else None,
            kind.decode() if kind else None)


def short(name):
    return name.split(".")[-1] if name else name


def main(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("mcap")
    p.add_argument("--rrd")
    p.add_argument("--expect-transforms", action="store_true")
    p.add_argument("--expect-scene", action="store_true")
    p.add_argument("--expect-images", action="store_true")
    args = p.parse_args(argv)
    rerun_cli = os.path.join(os.path.dirname(sys.executable), "rerun")
    out = args.rrd or os.path.join(tempfile.mkdtemp(prefix="rrd_check"), "log.rrd")
    done = subprocess.run([rerun_cli, "mcap", "convert", args.mcap, "-o", out],
                          capture_output=True, text=True)
    report = {"mcap": args.mcap, "rrd": out, "entities": {}, "errors": []}
    if done.returncode != 0:
        report["errors"].append(f"rerun mcap convert failed ({done.returncode}): {done.stderr.strip()}")
        print(json.dumps(report))
        return 1
    entities = report["entities"]
    for chunk in RrdReader(out).stream():
        path = chunk.entity_path
        entry = entities.setdefault(path, {"archetypes": [], "components": [], "rows": 0,
                                           "static_rows": 0})
        if chunk.is_static:
            entry["static_rows"] += chunk.num_rows
        else:
            entry["rows"] += chunk.num_rows
        for field in chunk.to_record_batch().schema:
            arch, comp, kind = column_archetype(field)
            if kind in ("index", "control"):
                continue
            if arch and short(arch) not in entry["archetypes"]:
                entry["archetypes"].append(short(arch))
            if comp and comp not in entry["components"]:
                entry["components"].append(comp)
    for path, entry in entities.items():
        entry["semantic"] = any(a not in RAW for a in entry["archetypes"])

    def find(topic):
        # Rerun names an MCAP channel's entity after its topic.
        for path, entry in entities.items():
            if path.rstrip("/") == topic or path.rstrip("/").endswith(topic):
                return path, entry
        return None, None

    if args.expect_transforms:
        path, entry = find("/scene/tf")
        if entry is None:
            report["errors"].append("no entity for /scene/tf")
        elif "Transform3D" not in entry["archetypes"] or entry["rows"] == 0:
            report["errors"].append(f"{path}: no Transform3D rows ({entry['archetypes']})")
    if args.expect_scene:
        for topic in ("/scene/static", "/scene/dynamic", "/scene/targets"):
            path, entry = find(topic)
            if entry is None:
                report["errors"].append(f"no entity for {topic}")
            elif not entry["semantic"]:
                report["errors"].append(f"{path}: raw bytes only ({entry['archetypes']})")
    if args.expect_images:
        wanted = {"/image": "EncodedImage", "/calibration": "Pinhole"}
        cameras = [p for p in entities if "/camera/" in p and p.rstrip("/").endswith("/image")]
        if not cameras:
            report["errors"].append("no /camera/<name>/image entity")
        for path, entry in entities.items():
            topic = path.rstrip("/")
            if "/camera/" not in topic:
                continue
            kind = next((a for end, a in wanted.items() if topic.endswith(end)), None)
            if topic.endswith("/camera/tf"):
                kind = "Transform3D"
            if kind and (kind not in entry["archetypes"] or entry["rows"] == 0):
                report["errors"].append(f"{path}: no {kind} rows ({entry['archetypes']})")
    print(json.dumps(report))
    return 1 if report["errors"] else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
