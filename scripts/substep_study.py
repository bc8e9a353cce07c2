#!/usr/bin/env python3
"""Summarises scripts/substep-study.sh: tracking errors, speed and benchmark success per count
of physics substeps, and each count's differences from the default (4). Prints Markdown tables
and writes OUT/summary.json."""
import json
import pathlib
import sys

out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "runs/substeps")
counts = sorted(int(p.name[1:]) for p in out.glob("n*") if p.name[1:].isdigit())
summary = {}
for n in counts:
    d = out / f"n{n}"
    row = {}
    for flight in ("hover", "step", "ee-step", "omni"):
        r = json.loads((d / f"{flight}.json").read_text())
        row[flight] = {
            "base_pos_rmse_m": r["base_pos_rmse_m"],
            "ee_pos_rmse_m": r["ee_pos_rmse_m"],
            "max_rotor_thrust_n": r["max_rotor_thrust_n"],
            "saturation_rate": r["saturation_rate"],
            "ticks_per_second": r["ticks_per_second"],
            "wall_time_s": float((d / f"{flight}.time").read_text()),
        }
    b = json.loads((d / "bench.json").read_text())
    tasks = b.get("tasks") or b.get("results") or {}
    row["bench"] = {
        "env_steps_per_second": b["timing"]["env_steps_per_second"],
        "tasks": {
            t: {
                "successes": s["successes"],
                "rollouts": s["rollouts"],
                "subtask_completion": s["subtask_completion"],
                "norm_ee_error": s["norm_ee_error"],
            }
            for t, s in tasks.items()
        },
    }
    summary[n] = row
(out / "summary.json").write_text(json.dumps(summary, indent=2))

print("| substeps | hover base RMSE (mm) | x step base RMSE (mm) | EE step EE RMSE (mm) | Omni EE step EE RMSE (mm) | hover ticks/s (track) | bench env steps/s |")
print("|---|---|---|---|---|---|---|")
for n, r in summary.items():
    print(
        f"| {n} | {1e3 * r['hover']['base_pos_rmse_m']:.4f} | {1e3 * r['step']['base_pos_rmse_m']:.2f}"
        f" | {1e3 * r['ee-step']['ee_pos_rmse_m']:.2f} | {1e3 * r['omni']['ee_pos_rmse_m']:.2f}"
        f" | {r['hover']['ticks_per_second']:.0f} | {r['bench']['env_steps_per_second']:.0f} |"
    )
print()
tasks = sorted({t for r in summary.values() for t in r["bench"]["tasks"]})
print("| substeps | " + " | ".join(f"{t} successes (subtask %)" for t in tasks) + " |")
print("|---|" + "---|" * len(tasks))
for n, r in summary.items():
    cells = []
    for t in tasks:
        s = r["bench"]["tasks"].get(t)
        cells.append(
            "-" if s is None
            else f"{s['successes']}/{s['rollouts']}"
            + ("" if s["subtask_completion"] is None else f" ({100 * s['subtask_completion']:.0f} %)")
        )
    print(f"| {n} | " + " | ".join(cells) + " |")
