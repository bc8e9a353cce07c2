#!/usr/bin/env python3
"""Small ONNX policies for amstack's tests, made with the `onnx` helper API, and their
reference outputs from PyPI `onnxruntime` (not amstack's code).

  onnx_model.py make --out M.onnx [--state-keys ee_pos,ee_quat,gripper_width] [--horizon 4]
                     [--dim 8] [--hidden 32] [--seed 0] [--semantics absolute]
      writes M.onnx (an MLP: Gemm, Tanh, Gemm, Reshape, then the quaternion of every action
      normalised in the graph: Slice, Mul, ReduceSum, Sqrt, Div, Concat) and its sidecar
      M.onnx.json (docs/policies.md), with seeded random weights and state statistics.
  onnx_model.py run --model M.onnx --inputs X.json
      prints {"outputs": [...]} : onnxruntime's output (flattened) for each input row of X.json
      (a JSON list of state vectors, already normalised as the model takes them).
"""

import argparse
import json
import sys

import numpy as np

KEY_LEN = {"ee_pos": 3, "ee_quat": 4, "gripper_width": 1, "base_pos": 3, "base_quat": 4}


def make(args):
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    keys = args.state_keys.split(",")
    d = sum(KEY_LEN.get(k, args.arm_joints) for k in keys)
    h, a = args.horizon, args.dim
    rng = np.random.default_rng(args.seed)
    w1 = rng.normal(0, 1 / np.sqrt(d), (d, args.hidden)).astype(np.float32)
    b1 = rng.normal(0, 0.1, args.hidden).astype(np.float32)
    w2 = rng.normal(0, 1 / np.sqrt(args.hidden), (args.hidden, h * a)).astype(np.float32)
    b2 = rng.normal(0, 0.1, h * a).astype(np.float32)
    # Bias the quaternion's w so the normalised quaternion stays near identity.
    b2.reshape(h, a)[:, 3] += 3.0
    init = [
        numpy_helper.from_array(w1, "w1"),
        numpy_helper.from_array(b1, "b1"),
        numpy_helper.from_array(w2, "w2"),
        numpy_helper.from_array(b2, "b2"),
        numpy_helper.from_array(np.array([1, h, a], np.int64), "shape"),
        numpy_helper.from_array(np.array([0], np.int64), "s0"),
        numpy_helper.from_array(np.array([3], np.int64), "s3"),
        numpy_helper.from_array(np.array([7], np.int64), "s7"),
        numpy_helper.from_array(np.array([a], np.int64), "sa"),
        numpy_helper.from_array(np.array([2], np.int64), "axis2"),
    ]
    nodes = [
        helper.make_node("Gemm", ["state", "w1", "b1"], ["h1"]),
        helper.make_node("Tanh", ["h1"], ["t1"]),
        helper.make_node("Gemm", ["t1", "w2", "b2"], ["flat"]),
        helper.make_node("Reshape", ["flat", "shape"], ["raw"]),
        helper.make_node("Slice", ["raw", "s0", "s3", "axis2"], ["pos"]),
        helper.make_node("Slice", ["raw", "s3", "s7", "axis2"], ["quat"]),
        helper.make_node("Slice", ["raw", "s7", "sa", "axis2"], ["rest"]),
        helper.make_node("Mul", ["quat", "quat"], ["sq"]),
        helper.make_node("ReduceSum", ["sq", "axis2"], ["ss"], keepdims=1),
        helper.make_node("Sqrt", ["ss"], ["norm"]),
        helper.make_node("Div", ["quat", "norm"], ["unit"]),
        helper.make_node("Concat", ["pos", "unit", "rest"], ["actions"], axis=2),
    ]
    graph = helper.make_graph(
        nodes,
        "amstack_test_policy",
        [helper.make_tensor_value_info("state", TensorProto.FLOAT, [1, d])],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [1, h, a])],
        init,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, args.out)
    sidecar = {
        "state": {
            "input": "state",
            "keys": keys,
            "mean": rng.normal(0, 0.1, d).round(4).tolist(),
            "std": (1 + rng.random(d)).round(4).tolist(),
        },
        "output": {"output": "actions", "chunk": h, "dim": a, "semantics": args.semantics},
        "rates": {"policy_hz": 20, "action_steps": min(h, 8)},
    }
    with open(args.out + ".json", "w") as f:
        json.dump(sidecar, f, indent=2)
    print(json.dumps({"model": args.out, "state_dim": d, "horizon": h, "dim": a}))


def run(args):
    import onnxruntime as ort

    session = ort.InferenceSession(args.model, providers=["CPUExecutionProvider"])
    with open(args.inputs) as f:
        rows = json.load(f)
    outputs = []
    for row in rows:
        x = np.array([row], dtype=np.float32)
        (y,) = session.run(None, {session.get_inputs()[0].name: x})
        outputs.append(y.astype(np.float64).ravel().tolist())
    print(json.dumps({"outputs": outputs, "onnxruntime": ort.__version__}))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    m = sub.add_parser("make")
    m.add_argument("--out", required=True)
    m.add_argument("--state-keys", default="ee_pos,ee_quat,gripper_width")
    m.add_argument("--arm-joints", type=int, default=4)
    m.add_argument("--horizon", type=int, default=4)
    m.add_argument("--dim", type=int, default=8)
    m.add_argument("--hidden", type=int, default=32)
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--semantics", choices=["absolute", "relative"], default="absolute")
    r = sub.add_parser("run")
    r.add_argument("--model", required=True)
    r.add_argument("--inputs", required=True)
    args = p.parse_args()
    make(args) if args.command == "make" else run(args)


if __name__ == "__main__":
    sys.exit(main())
