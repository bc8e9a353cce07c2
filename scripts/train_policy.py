#!/usr/bin/env python3
"""Behaviour cloning from a dataset `amstack record` wrote: a small MLP policy, exported to ONNX
with the sidecar `amstack bench --policy onnx:MODEL` reads (docs/policies.md).

  train_policy.py DATASET [DATASET...] --out MODEL.onnx [--horizon 8] [--policy-hz 20]
                  [--action-steps 8] [--hidden 256,256] [--max-iter 300] [--seed 0]
                  [--json REPORT.json]

What it learns (the chunked interface of AMBENCH_SPEC §5.3): at every policy step of an episode
(raw frame k = 0, s, 2s, ... with s = fps / policy-hz, 120 / 20 = 6), from the observation state
of frame k (the dataset's `observation.state`, its keys in info.json), the chunk of H absolute
actions A[k + s*i + s - 1], i < H (each macro action the demonstration's target at the tick it
is reached; padded with the episode's last action) -- what `scripts/openpi_server.py --mode
replay` answers, so a perfect fit replays the demonstrations.

The network: scikit-learn's MLPRegressor (Adam, ReLU, early stopping on 10 % of the episodes),
inputs and targets standardised. The ONNX graph (the `onnx` helper API) is the MLP's Gemm/Relu
layers, a Reshape to [1, H, D], the action values that are constant over the demonstrations
set to that constant (Mul, Add) and, for every action, the quaternion normalised (Slice, Mul,
ReduceSum, Sqrt, Div, Concat); the sidecar carries the state's keys and statistics and the
output's (quaternion statistics 0/1: amstack undoes them after the graph). The export is checked
against scikit-learn's own prediction through PyPI onnxruntime before it is written.

Reads the Parquet files with pyarrow; needs the venv of scripts/setup-python.sh. Prints a summary
line; --json writes the figures (samples, episodes, validation error, training time, the ONNX
check). Exit 2 on bad input (a path or a dataset that is not one), with one line naming it.
"""

import argparse
import glob
import json
import os
import sys
import time

import numpy as np


def fail(message):
    print(f"train_policy.py: {message}", file=sys.stderr)
    sys.exit(2)


def load(root):
    import pyarrow.parquet as pq

    info_path = os.path.join(root, "meta", "info.json")
    try:
        with open(info_path) as f:
            info = json.load(f)
    except (OSError, ValueError) as e:
        fail(f"{info_path}: not a dataset written by `amstack record` ({e})")
    semantics = info.get("ambench", {}).get("action_semantics")
    if semantics not in ("ee_absolute", "base_joint_absolute"):
        fail(f"{info_path}: ambench.action_semantics {semantics!r}: expected ee_absolute or base_joint_absolute")
    files = sorted(glob.glob(os.path.join(root, "data", "chunk-*", "file-*.parquet")))
    if not files:
        fail(f"{root}: no data/chunk-*/file-*.parquet")
    columns = ["observation.state", "action", "episode_index", "frame_index"]
    episodes = {}
    for path in files:
        t = pq.read_table(path, columns=columns)
        state = np.asarray(t.column("observation.state").to_pylist(), dtype=np.float64)
        action = np.asarray(t.column("action").to_pylist(), dtype=np.float64)
        ep = np.asarray(t.column("episode_index").to_pylist())
        frame = np.asarray(t.column("frame_index").to_pylist())
        for e in np.unique(ep):
            rows = ep == e
            order = np.argsort(frame[rows])
            episodes[(root, int(e))] = (state[rows][order], action[rows][order])
    return info, episodes


def samples(episodes, stride, horizon):
    xs, ys, groups = [], [], []
    for g, (state, action) in enumerate(episodes.values()):
        n = len(state)
        for k in range(0, n, stride):
            idx = [min(k + stride * i + stride - 1, n - 1) for i in range(horizon)]
            xs.append(state[k])
            ys.append(action[idx].ravel())
            groups.append(g)
    return np.array(xs), np.array(ys), np.array(groups)


def onnx_graph(mlp, d, horizon, dim, quat_at, keep, fixed):
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    init, nodes = [], []
    x = "state"
    last = len(mlp.coefs_) - 1
    for i, (w, b) in enumerate(zip(mlp.coefs_, mlp.intercepts_)):
        init += [numpy_helper.from_array(w.astype(np.float32), f"w{i}"),
                 numpy_helper.from_array(b.astype(np.float32), f"b{i}")]
        y = "flat" if i == last else f"h{i}"
        nodes.append(helper.make_node("Gemm", [x, f"w{i}", f"b{i}"], [y]))
        if i != last:
            nodes.append(helper.make_node("Relu", [y], [f"r{i}"]))
            y = f"r{i}"
        x = y
    q0, q1 = quat_at, quat_at + 4
    init += [
        numpy_helper.from_array(np.array([1, horizon, dim], np.int64), "shape"),
        numpy_helper.from_array(keep.astype(np.float32), "keep"),
        numpy_helper.from_array(fixed.astype(np.float32), "fixed"),
        numpy_helper.from_array(np.array([0], np.int64), "s0"),
        numpy_helper.from_array(np.array([q0], np.int64), "sq0"),
        numpy_helper.from_array(np.array([q1], np.int64), "sq1"),
        numpy_helper.from_array(np.array([dim], np.int64), "sdim"),
        numpy_helper.from_array(np.array([2], np.int64), "axis2"),
    ]
    nodes += [
        helper.make_node("Reshape", ["flat", "shape"], ["free"]),
        # Action values constant over the demonstrations are answered as that constant.
        helper.make_node("Mul", ["free", "keep"], ["kept"]),
        helper.make_node("Add", ["kept", "fixed"], ["raw"]),
        helper.make_node("Slice", ["raw", "s0", "sq0", "axis2"], ["head"]),
        helper.make_node("Slice", ["raw", "sq0", "sq1", "axis2"], ["quat"]),
        helper.make_node("Slice", ["raw", "sq1", "sdim", "axis2"], ["rest"]),
        helper.make_node("Mul", ["quat", "quat"], ["sq"]),
        helper.make_node("ReduceSum", ["sq", "axis2"], ["ss"], keepdims=1),
        helper.make_node("Sqrt", ["ss"], ["norm"]),
        helper.make_node("Div", ["quat", "norm"], ["unit"]),
        helper.make_node("Concat", ["head", "unit", "rest"], ["actions"], axis=2),
    ]
    graph = helper.make_graph(
        nodes, "amstack_bc_policy",
        [helper.make_tensor_value_info("state", TensorProto.FLOAT, [1, d])],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, horizon, dim])],
        init)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("datasets", nargs="+", metavar="DATASET")
    p.add_argument("--out", required=True, help="the ONNX model (its sidecar: OUT.json)")
    p.add_argument("--horizon", type=int, default=8, help="actions per chunk, H (>= --action-steps)")
    p.add_argument("--policy-hz", type=int, default=20)
    p.add_argument("--action-steps", type=int, default=8, help="the sidecar's default --action-steps")
    p.add_argument("--hidden", default="256,256", help="hidden layer widths")
    p.add_argument("--max-iter", type=int, default=300, help="Adam epochs at most")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", help="write the figures here")
    args = p.parse_args()
    if args.horizon < 1 or args.action_steps < 1 or args.action_steps > args.horizon:
        fail(f"--horizon {args.horizon} --action-steps {args.action_steps}: need 1 <= action-steps <= horizon")
    try:
        hidden = tuple(int(h) for h in args.hidden.split(","))
    except ValueError:
        fail(f"--hidden {args.hidden!r}: expected comma-separated widths")

    from sklearn.model_selection import GroupShuffleSplit
    from sklearn.neural_network import MLPRegressor

    started = time.monotonic()
    episodes, info = {}, None
    for root in args.datasets:
        i, e = load(root)
        if info is not None and (i["ambench"]["state_keys"] != info["ambench"]["state_keys"]
                                 or i["ambench"]["action_semantics"] != info["ambench"]["action_semantics"]
                                 or i["fps"] != info["fps"]):
            fail(f"{root}: state keys, action semantics or fps differ from {args.datasets[0]}'s")
        info = info or i
        episodes.update(e)
    fps = int(info["fps"])
    if fps % args.policy_hz:
        fail(f"--policy-hz {args.policy_hz} does not divide the dataset's {fps} fps")
    stride = fps // args.policy_hz
    keys = info["ambench"]["state_keys"]
    x, y, groups = samples(episodes, stride, args.horizon)
    d, dim = x.shape[1], y.shape[1] // args.horizon
    quat_at = 3  # [x y z qw qx qy qz ...] for both action layouts
    x_mean, x_std = x.mean(0), x.std(0)
    x_std[x_std < 1e-6] = 1.0
    per = y.reshape(-1, dim)
    a_mean, a_std = per.mean(0), per.std(0)
    constant = a_std < 1e-6
    a_std[constant] = 1.0
    a_mean[quat_at:quat_at + 4], a_std[quat_at:quat_at + 4] = 0.0, 1.0
    # The graph answers constant action values exactly (standardised: 0; a quaternion's
    # component, not standardised: its value).
    keep = np.where(constant, 0.0, 1.0)
    fixed = np.where(constant, (per[0] - a_mean) / a_std, 0.0)
    xn = (x - x_mean) / x_std
    yn = ((y.reshape(len(y), args.horizon, dim) - a_mean) / a_std).reshape(len(y), -1)

    split = GroupShuffleSplit(n_splits=1, test_size=0.1, random_state=args.seed)
    train, val = next(split.split(xn, yn, groups))
    mlp = MLPRegressor(hidden_layer_sizes=hidden, activation="relu", solver="adam",
                       learning_rate_init=1e-3, batch_size=256, max_iter=args.max_iter,
                       early_stopping=True, validation_fraction=0.1, n_iter_no_change=20,
                       random_state=args.seed)
    mlp.fit(xn[train], yn[train])
    trained_s = time.monotonic() - started

    def fix(yhat):
        return yhat.reshape(len(yhat), args.horizon, dim) * keep + fixed

    def unnormalise(yhat):
        a = fix(yhat) * a_std + a_mean
        q = a[:, :, quat_at:quat_at + 4]
        a[:, :, quat_at:quat_at + 4] = q / np.linalg.norm(q, axis=2, keepdims=True)
        return a

    pred_val = unnormalise(mlp.predict(xn[val]))
    true_val = y[val].reshape(len(val), args.horizon, dim)
    pos_err = np.linalg.norm(pred_val[:, :, :3] - true_val[:, :, :3], axis=2)

    model = onnx_graph(mlp, d, args.horizon, dim, quat_at, keep, fixed)
    import onnx
    import onnxruntime as ort

    # The export gives what scikit-learn predicts (float32 kernels: 1e-4 of the standardised scale).
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    check = xn[val[:64]].astype(np.float32)
    ours = np.concatenate([session.run(None, {"state": row[None]})[0] for row in check])
    ref = fix(mlp.predict(xn[val[:64]]))
    q = ref[:, :, quat_at:quat_at + 4]
    ref[:, :, quat_at:quat_at + 4] = q / np.linalg.norm(q, axis=2, keepdims=True)
    onnx_err = float(np.abs(ours - ref).max())
    if not onnx_err < 1e-4:
        fail(f"the ONNX export differs from scikit-learn by {onnx_err}")

    out_dir = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(out_dir, exist_ok=True)
    tmp = args.out + ".tmp"
    onnx.save(model, tmp)
    os.replace(tmp, args.out)
    r = lambda v: [float(f"{z:.9g}") for z in v]  # noqa: E731
    sidecar = {
        "state": {"input": "state", "keys": keys, "mean": r(x_mean), "std": r(x_std)},
        "output": {"output": "actions", "chunk": args.horizon, "dim": dim, "semantics": "absolute",
                   "mean": r(a_mean), "std": r(a_std)},
        "rates": {"policy_hz": args.policy_hz, "action_steps": args.action_steps},
    }
    with open(args.out + ".json.tmp", "w") as f:
        json.dump(sidecar, f, indent=2)
    os.replace(args.out + ".json.tmp", args.out + ".json")
    report = {
        "model": args.out,
        "datasets": args.datasets,
        "episodes": len(episodes),
        "samples": int(len(x)),
        "train_samples": int(len(train)),
        "validation_samples": int(len(val)),
        "state_keys": keys,
        "state_dim": int(d),
        "horizon": args.horizon,
        "action_dim": int(dim),
        "stride": stride,
        "hidden": list(hidden),
        "epochs": int(mlp.n_iter_),
        "constant_action_values": [int(i) for i in np.flatnonzero(constant)],
        "validation_position_error_m": {"mean": float(pos_err.mean()), "p95": float(np.percentile(pos_err, 95))},
        "onnx_vs_sklearn_max_abs": onnx_err,
        "train_time_s": trained_s,
        "sklearn": __import__("sklearn").__version__,
        "onnxruntime": ort.__version__,
    }
    print(f"trained on {report['train_samples']} samples of {report['episodes']} episodes "
          f"({report['epochs']} epochs, {trained_s:.1f} s); validation EE position error "
          f"mean {pos_err.mean() * 100:.2f} cm, p95 {np.percentile(pos_err, 95) * 100:.2f} cm; "
          f"ONNX = scikit-learn to {onnx_err:.1e}; wrote {args.out} and {args.out}.json")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)


if __name__ == "__main__":
    main()
