"""Compares `amstack platforms --dynamics FILE` with Pinocchio on the built-in vehicles' URDFs.

    python pinocchio_peer.py DYNAMICS.json VEHICLES_DIR

For every vehicle and sample: Pinocchio's model of VEHICLES_DIR/<id>.urdf with a free-flyer
root, the sample's joint positions and rates placed at Pinocchio's indices (by joint name),
the base attitude as the free-flyer's quaternion; M from `crba` (upper triangle, mirrored), b
from `rnea` at zero acceleration (gravity (0, 0, -9.81)), and the forward dynamics at the
sample's τ from `aba` (the articulated-body algorithm: no mass matrix, no factorisation, so it
checks amstack's LᵀDL factor and solve independently). Prints the largest differences and
exits 1 if one exceeds 1e-9 of the largest entry of its matrix or vector.
"""

import json
import sys

import numpy as np
import pinocchio as pin

TOLERANCE = 1e-9


def main() -> int:
    dynamics = json.load(open(sys.argv[1]))
    vehicles_dir = sys.argv[2]
    worst_all = 0.0
    print(f"Pinocchio {pin.__version__}")
    print("| vehicle | bodies | nv | samples | max |M - M_pin| / max |M| | max |b - b_pin| / max |b| "
          "| max |a - a_pin| / max |a| |")
    print("|---|---|---|---|---|---|---|")
    for vid, entry in dynamics.items():
        model = pin.buildModelFromUrdf(f"{vehicles_dir}/{vid}.urdf", pin.JointModelFreeFlyer())
        data = model.createData()
        nv = 6 + len(entry["joints"])
        if model.nv != nv:
            print(f"{vid}: Pinocchio has nv = {model.nv}, amstack {nv}")
            return 1
        q_index, v_index = [], list(range(6))
        for name in entry["joints"]:
            jid = model.getJointId(name)
            q_index.append(model.joints[jid].idx_q)
            v_index.append(model.joints[jid].idx_v)
        worst_m = worst_b = worst_a = 0.0
        for s in entry["samples"]:
            q = np.zeros(model.nq)
            w, x, y, z = s["attitude_wxyz"]
            q[3:7] = [x, y, z, w]
            for k, value in zip(q_index, s["q"]):
                q[k] = value
            v = np.zeros(model.nv)
            for ours, theirs in enumerate(v_index):
                v[theirs] = s["nu"][ours]
            m_pin = pin.crba(model, data, q)
            m_pin = np.triu(m_pin) + np.triu(m_pin, 1).T
            b_pin = pin.rnea(model, data, q, v, np.zeros(model.nv))
            tau = np.zeros(model.nv)
            for ours, theirs in enumerate(v_index):
                tau[theirs] = s["tau"][ours]
            a_pin = pin.aba(model, data, q, v, tau)[v_index]
            a_ours = np.array(s["acceleration"], dtype=float)
            if not np.all(np.isfinite(a_ours)):
                print(f"{vid}: amstack's forward dynamics failed (non-finite) at a sample")
                return 1
            worst_a = max(worst_a, np.abs(a_ours - a_pin).max() / max(np.abs(a_pin).max(), 1.0))
            # Pinocchio's entries in amstack's order.
            m_pin = m_pin[np.ix_(v_index, v_index)]
            b_pin = b_pin[v_index]
            m_ours = np.array(s["mass_matrix"])
            b_ours = np.array(s["bias"])
            worst_m = max(worst_m, np.abs(m_ours - m_pin).max() / np.abs(m_pin).max())
            worst_b = max(worst_b, np.abs(b_ours - b_pin).max() / max(np.abs(b_pin).max(), 1.0))
        worst_all = max(worst_all, worst_m, worst_b, worst_a)
        print(f"| {vid} | {entry['bodies']} | {nv} | {len(entry['samples'])} | {worst_m:.2e} "
              f"| {worst_b:.2e} | {worst_a:.2e} |")
    verdict = "agree" if worst_all <= TOLERANCE else "DIFFER"
    print(f"{verdict}: largest relative difference {worst_all:.2e} (tolerance {TOLERANCE:.0e})")
    return 0 if worst_all <= TOLERANCE else 1


if __name__ == "__main__":
    sys.exit(main())
