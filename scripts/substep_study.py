#!/usr/bin/env python3
"""Summarises scripts/substep-study.sh: for each (P physics substeps, I solver iterations,
S rapier solver steps) setting, the tracking errors, the validation experiments, the benchmark's successes and the
grasped objects' trajectories from the rollouts' MCAPs, each against the default 4x4; the
fidelity bar of issue 22 (tracking within 1 %, validation within 5 %, successes within 1
rollout per task). Prints Markdown tables and writes OUT/summary.json.

    python3 scripts/substep_study.py OUT     (the MCAP part needs the PyPI `mcap` reader:
                                               bash scripts/setup-python.sh)
"""
import json
import math
import pathlib
import re
import sys

out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "runs/substeps")
# (P, I, S): a folder pPiI is rapier's split before `--rapier-steps` (I steps of one pass,
# S = I), pPiIsS the I passes over S steps.
REF = (4, 4, 4)
pairs = sorted(
    (
        (int(m[1]), int(m[2]), int(m[3] or m[2]))
        for p in out.glob("p*i*")
        if (m := re.fullmatch(r"p(\d+)i(\d+)(?:s(\d+))?", p.name))
    ),
    key=lambda pi: (-pi[0] * pi[1], -pi[0], -pi[2]),
)
if REF not in pairs:
    sys.exit(f"{out}: no p4i4 folder (the 4x4 reference, which every pair is compared with)")


def label(pair):
    return f"{pair[0]}x{pair[1]}" + ("" if pair[2] == pair[1] else f"s{pair[2]}")


def folder(pair):
    return out / ("p" + label(pair).replace("x", "i"))


def load(path):
    return json.loads(path.read_text()) if path.exists() else None


def tracking(d):
    row = {}
    for flight in ("hover", "step", "ee-step", "omni"):
        r = load(d / f"{flight}.json")
        if r is None:
            continue
        row[flight] = {
            "base_pos_rmse_m": r["base_pos_rmse_m"],
            "ee_pos_rmse_m": r["ee_pos_rmse_m"],
            "max_rotor_thrust_n": r["max_rotor_thrust_n"],
            "ticks_per_second": r["ticks_per_second"],
        }
    return row


def validation(d):
    """The experiments' headline figures, by name."""
    v = {}
    a = load(d / "exp-actuator" / "actuator.json")
    if a:
        for r in a["rows"]:
            for band in ("low", "high"):
                v[f"actuator {r['key']} {band} base-z RMSE (m)"] = r[band]["base_z_rmse_m"]
    g = load(d / "exp-ground-effect" / "ground-effect.json")
    if g:
        for model in ("without", "with"):
            for interval in ("near_ground", "high"):
                v[f"ground-effect {model} model EE-z RMSE {interval} (m)"] = (
                    g[model]["ee_z_rmse_cm"][interval] / 100.0
                )
        v["ground-effect near-ground reduction (%)"] = g["near_ground_reduction_pct"]
    w = load(d / "exp-wrench-limit" / "wrench-limit.json")
    if w:
        for r in w["responses"]:
            v[f"wrench-limit {r['limit']} lowest base z (m)"] = r["min_base_z_m"]
            v[f"wrench-limit {r['limit']} x arrival (s)"] = r["x_arrival_s"]
            v[f"wrench-limit {r['limit']} base position RMSE (m)"] = r["base_pos_rmse_m"]
    return v


def bench(d):
    b = load(d / "bench.json")
    if b is None:
        return None
    tasks = b.get("tasks") or b.get("results") or {}
    return {
        "env_steps_per_second": b["timing"]["env_steps_per_second"],
        "tasks": {
            t: {
                "successes": s["successes"],
                "rollouts": s["rollouts"],
                "subtask_completion": s["subtask_completion"],
            }
            for t, s in tasks.items()
        },
    }


# The grasped object of each carrying task: its position in /task/state's observation.
CARRIED = {
    "cabinet-pick-place": "can_pos",
    "frame-assembly": "frame_pos",
    "lemon-harvesting": "lemon_pos",
}


def quat_rotate_inverse(q, v):
    """q = (x, y, z, w) unit; returns q^-1 v."""
    x, y, z, w = q
    x, y, z = -x, -y, -z
    tx = 2 * (y * v[2] - z * v[1])
    ty = 2 * (z * v[0] - x * v[2])
    tz = 2 * (x * v[1] - y * v[0])
    return (
        v[0] + w * tx + (y * tz - z * ty),
        v[1] + w * ty + (z * tx - x * tz),
        v[2] + w * tz + (x * ty - y * tx),
    )


def object_track(mcap_path, name):
    """Per tick: the object's position (world) and, while held, in the EE frame."""
    from mcap.reader import make_reader

    ee = []
    obj = []
    held = []
    with open(mcap_path, "rb") as f:
        for _, ch, msg in make_reader(f).iter_messages(topics=["/task/state", "/ee/pose"]):
            d = json.loads(msg.data)
            if ch.topic == "/ee/pose":
                p = d["pose"]
                ee.append(
                    (
                        (p["position"]["x"], p["position"]["y"], p["position"]["z"]),
                        (
                            p["orientation"]["x"],
                            p["orientation"]["y"],
                            p["orientation"]["z"],
                            p["orientation"]["w"],
                        ),
                    )
                )
            else:
                o = next(o["values"] for o in d["observation"] if o["name"] == name)
                obj.append(tuple(o))
                held.append(bool(d.get("holding")))
    n = min(len(ee), len(obj))
    # Slip: within each held stretch in which the object is carried (it moves > 2 cm in the
    # world), its largest move in the EE frame from where it was at the stretch's start.
    held_ticks, slip, start = 0, None, None
    for k in range(n + 1):
        if k < n and held[k]:
            held_ticks += 1
            start = k if start is None else start
            continue
        if start is not None:
            span = range(start, k)
            travel = max(math.dist(obj[j], obj[start]) for j in span)
            if travel > 0.02:
                rel = [
                    quat_rotate_inverse(ee[j][1], [obj[j][i] - ee[j][0][i] for i in range(3)])
                    for j in span
                ]
                s_ = max(math.dist(r, rel[0]) for r in rel)
                slip = s_ if slip is None else max(slip, s_)
            start = None
    return {"world": obj[:n], "held_ticks": held_ticks, "slip_m": slip}


def contact(pair):
    """Per carrying task, over the rollouts both runs hold: slip while held, and the
    object's distance from its 4x4 trajectory (RMS over the common ticks, and at the end)."""
    rows = {}
    for task, name in CARRIED.items():
        ref_dir = folder(REF) / "bench" / "rollouts" / task
        dir_ = folder(pair) / "bench" / "rollouts" / task
        if not dir_.is_dir() or not ref_dir.is_dir():
            continue
        slips, held, rms, final = [], [], [], []
        for m in sorted(dir_.glob("rollout-*.mcap")):
            ref = ref_dir / m.name
            if not ref.exists():
                continue
            a, b = object_track(m, name), object_track(ref, name)
            held.append(a["held_ticks"])
            if a["slip_m"] is not None:
                slips.append(a["slip_m"])
            n = min(len(a["world"]), len(b["world"]))
            if n:
                dists = [math.dist(a["world"][k], b["world"][k]) for k in range(n)]
                rms.append(math.sqrt(sum(x * x for x in dists) / n))
                final.append(math.dist(a["world"][-1], b["world"][-1]))
        if held:
            rows[task] = {
                "rollouts": len(held),
                "mean_held_ticks": sum(held) / len(held),
                "max_slip_m": max(slips) if slips else None,
                "mean_slip_m": sum(slips) / len(slips) if slips else None,
                "median_rms_from_4x4_m": sorted(rms)[len(rms) // 2] if rms else None,
                "max_rms_from_4x4_m": max(rms) if rms else None,
                "median_final_from_4x4_m": sorted(final)[len(final) // 2] if final else None,
            }
    return rows


summary = {}
for pair in pairs:
    d = folder(pair)
    row = {"tracking": tracking(d), "validation": validation(d), "bench": bench(d)}
    try:
        row["contact"] = contact(pair)
    except ImportError:
        row["contact"] = None
    summary[label(pair)] = row

ref = summary["4x4"]


def rel(a, b):
    return (a - b) / b if b else (0.0 if a == b else math.inf)


# The fidelity bar of issue 22, per pair, against 4x4.
for key, row in summary.items():
    verdict = {}
    worst = {}
    for flight in ("step", "ee-step", "omni"):
        for metric in ("base_pos_rmse_m", "ee_pos_rmse_m"):
            if flight in row["tracking"] and flight in ref["tracking"]:
                worst[f"{flight} {metric}"] = rel(
                    row["tracking"][flight][metric], ref["tracking"][flight][metric]
                )
    verdict["tracking_worst_rel"] = max(worst.values(), key=abs) if worst else None
    verdict["tracking_within_1pct"] = bool(worst) and all(abs(x) <= 0.01 for x in worst.values())
    hover = {}
    for metric in ("base_pos_rmse_m", "ee_pos_rmse_m"):
        if "hover" in row["tracking"]:
            hover[metric] = row["tracking"]["hover"][metric] - ref["tracking"]["hover"][metric]
    verdict["hover_abs_change_m"] = hover
    val = {
        k: rel(v, ref["validation"][k])
        for k, v in row["validation"].items()
        if k in ref["validation"]
    }
    verdict["validation_rel"] = val
    # The model-on ground-effect errors are sim-against-sim at the micrometre level (1e-6 m):
    # reported, but the bar is on the figures the experiment is about.
    judged = {k: x for k, x in val.items() if "with model" not in k}
    verdict["validation_within_5pct"] = bool(judged) and all(abs(x) <= 0.05 for x in judged.values())
    if row["bench"] and ref["bench"]:
        diffs = {
            t: s["successes"] - ref["bench"]["tasks"][t]["successes"]
            for t, s in row["bench"]["tasks"].items()
            if t in ref["bench"]["tasks"]
        }
        verdict["success_diffs"] = diffs
        verdict["successes_within_1"] = all(abs(x) <= 1 for x in diffs.values())
    row["verdict"] = verdict
(out / "summary.json").write_text(json.dumps(summary, indent=2))

print("Tracking (RMSE, mm; worst relative change of the step flights from 4x4):\n")
print("| P x I | mass matrices per tick | hover base | hover EE | x step base | EE step EE | Omni EE step EE | worst change | within 1 % |")
print("|---|---|---|---|---|---|---|---|---|")
pair_of = {label(pair): pair for pair in pairs}
for key, r in summary.items():
    t = r["tracking"]
    p, _, steps = pair_of[key]
    cell = lambda f, m, nd: f"{1e3 * t[f][m]:.{nd}f}" if f in t else "-"
    w = r["verdict"]["tracking_worst_rel"]
    print(
        f"| {key} | {p * steps} | {cell('hover', 'base_pos_rmse_m', 4)} | {cell('hover', 'ee_pos_rmse_m', 4)}"
        f" | {cell('step', 'base_pos_rmse_m', 2)} | {cell('ee-step', 'ee_pos_rmse_m', 2)}"
        f" | {cell('omni', 'ee_pos_rmse_m', 2)} | {'-' if w is None else f'{100 * w:+.2f} %'}"
        f" | {'yes' if r['verdict']['tracking_within_1pct'] else 'NO'} |"
    )
print()


def verdict_row(label, keys, verdict):
    """A table row of yes/NO, one cell per setting, from each summary's verdict."""
    cells = ["yes" if summary[k]["verdict"].get(verdict) else "NO" for k in keys]
    return f"| {label} | " + " | ".join(cells) + " |"


names = list(ref["validation"])
if names:
    print("Validation experiments (relative change from 4x4):\n")
    keys = list(summary)
    print("| figure | 4x4 | " + " | ".join(k for k in keys if k != "4x4") + " |")
    print("|---|---|" + "---|" * (len(keys) - 1))
    for n in names:
        cells = []
        for k in keys:
            if k == "4x4":
                continue
            x = summary[k]["verdict"]["validation_rel"].get(n)
            cells.append("-" if x is None else f"{100 * x:+.1f} %")
        print(f"| {n} | {ref['validation'][n]:.4g} | " + " | ".join(cells) + " |")
    print(verdict_row("within 5 % (model-off and wrench-limit figures, actuator) |",
                      [k for k in keys if k != "4x4"], "validation_within_5pct"))
    print()
benched = [k for k, r in summary.items() if r["bench"]]
if benched:
    tasks = list(ref["bench"]["tasks"]) if ref["bench"] else []
    print("Benchmark successes (FA-Hexa, IK-PID, reference disturbances, seed 0):\n")
    print("| task | " + " | ".join(benched) + " |")
    print("|---|" + "---|" * len(benched))
    for t in tasks:
        cells = []
        for k in benched:
            s = summary[k]["bench"]["tasks"].get(t)
            cells.append("-" if s is None else f"{s['successes']}/{s['rollouts']}")
        print(f"| {t} | " + " | ".join(cells) + " |")
    print(verdict_row("within 1 rollout of 4x4, every task", benched, "successes_within_1"))
    print(
        "| env steps/s | "
        + " | ".join(f"{summary[k]['bench']['env_steps_per_second']:.0f}" for k in benched)
        + " |"
    )
    print()
    print("Grasped objects (held ticks, slip in the EE frame while held, distance from the 4x4 trajectory):\n")
    print("| P x I | task | rollouts | mean held ticks | mean / max slip (mm) | median / max RMS from 4x4 (mm) | median final distance from 4x4 (mm) |")
    print("|---|---|---|---|---|---|---|")
    mm = lambda x: "-" if x is None else f"{1e3 * x:.1f}"
    for k in benched:
        for t, c in (summary[k]["contact"] or {}).items():
            print(
                f"| {k} | {t} | {c['rollouts']} | {c['mean_held_ticks']:.0f}"
                f" | {mm(c['mean_slip_m'])} / {mm(c['max_slip_m'])}"
                f" | {mm(c['median_rms_from_4x4_m'])} / {mm(c['max_rms_from_4x4_m'])}"
                f" | {mm(c['median_final_from_4x4_m'])} |"
            )
