#!/usr/bin/env python3
"""A policy server speaking openpi's WebSocket protocol, for testing amstack's remote policies.

It is built on the PyPI package `openpi-client` (its `msgpack_numpy` is openpi's wire encoding)
and `websockets` (the library openpi's own server uses), not on amstack's code:

- on connect it sends its metadata (one binary msgpack frame);
- each binary frame is one observation; the answer is {"actions": float32 (H, D), ...};
- on an error it sends the traceback as a text frame and closes the connection, as
  openpi.serving.websocket_policy_server does.

It checks every key, dtype and shape amstack sends against the reference's openpi adapter
(AMBENCH_SPEC §5.1, §7.2): am_bench/ee_pos float32 (3,), am_bench/ee_quat float32 (4,) unit,
am_bench/gripper_width float32 (1,) (or with --interface base-joint: am_bench/base_pos,
am_bench/base_quat, am_bench/arm_joint_pos (N,)), optional am_bench/ee_image /
am_bench/base_image uint8 (H, W, 3), and prompt (str). A request that breaks the contract is
answered as a server error (text frame + close), so the flight ends `policy_failed` naming it.

Policies (--mode):
  goto      actions go from the observed EE (or base) position to the goal over the chunk:
            the position of the connection's first observation + --offset (absolute
            targets, orientation --quat, gripper --gripper)
  replay    the actions of a recorded demonstration (--demo: an MCAP's /action channel, or a
            JSON list of action rows), chunk by chunk: query j answers rows
            A[stride*(j*steps + i) + stride - 1], i < H (each macro action the demonstration's
            target at the tick it is reached), padded with the last
  onnx      an ONNX model and its sidecar (--model M.onnx, M.onnx.json: docs/policies.md) run by
            PyPI onnxruntime: the state of the sidecar's keys, standardised, in; the chunk out,
            its statistics undone (state-only models; the chunk length is the sidecar's)
Faults (--fault, from query --fault-after on; the queries before are answered normally):
  die           the process exits without a word
  timeout       never answers
  wrong-shape   actions (H, D - 1)
  nan           a NaN in the actions
  unnormalised  quaternions of norm 2
  error         raises (a text frame with the traceback, then close)

  python3 scripts/openpi_server.py --port 0 --mode goto --offset 0.1,0,0.1
prints `listening on ws://127.0.0.1:PORT` on stdout once it serves. --log FILE appends one JSON
line per request: the keys with their dtype and shape, the state values, the prompt.
"""

import argparse
import asyncio
import json
import os
import sys
import traceback

import numpy as np
import websockets.asyncio.server as ws_server
import websockets.exceptions
import websockets.frames
from openpi_client import msgpack_numpy


def parse_vector(text, n, name):
    values = [float(v) for v in text.split(",")]
    if len(values) != n:
        raise SystemExit(f"--{name}: expected {n} comma-separated numbers, got {text!r}")
    return np.array(values)


def load_demo(path):
    """Action rows of a demonstration: an amstack MCAP's /action channel, or a JSON list."""
    if path.endswith(".json"):
        with open(path) as f:
            return np.array(json.load(f), dtype=np.float64)
    from mcap.reader import make_reader  # the PyPI `mcap` package

    rows = []
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=["/action"]):
            a = json.loads(message.data)
            rows.append(a["position_m"] + a["orientation_wxyz"] + a["arm_joints_rad"] + [a["gripper"]])
    if not rows:
        raise SystemExit(f"--demo {path}: no /action messages")
    return np.array(rows, dtype=np.float64)


class Contract:
    """What amstack must send (the reference's openpi adapter)."""

    def __init__(self, args):
        if args.interface == "ee":
            self.state = {"am_bench/ee_pos": 3, "am_bench/ee_quat": 4, "am_bench/gripper_width": 1}
        else:
            self.state = {
                "am_bench/base_pos": 3,
                "am_bench/base_quat": 4,
                "am_bench/arm_joint_pos": args.arm_joints,
                "am_bench/gripper_width": 1,
            }
        self.images = ("am_bench/ee_image", "am_bench/base_image")
        self.prompt = args.prompt
        self.args = args

    def check(self, obs):
        if not isinstance(obs, dict):
            raise TypeError(f"observation is a {type(obs).__name__}, expected a map")
        expected = set(self.state) | {"prompt"}
        keys = set(obs)
        missing = expected - keys
        unknown = keys - expected - set(self.images)
        if missing or unknown:
            raise KeyError(f"observation keys: missing {sorted(missing)}, unexpected {sorted(unknown)}")
        for key, n in self.state.items():
            v = obs[key]
            if not isinstance(v, np.ndarray) or v.dtype != np.float32 or v.shape != (n,):
                raise TypeError(f"{key}: expected float32 ({n},), got {type(v).__name__} "
                                f"{getattr(v, 'dtype', None)} {getattr(v, 'shape', None)}")
            if not np.isfinite(v).all():
                raise ValueError(f"{key}: non-finite {v.tolist()}")
            if key.endswith("_quat") and abs(float(np.linalg.norm(v)) - 1.0) > 1e-5:
                raise ValueError(f"{key}: norm {np.linalg.norm(v)} is not 1")
        # A measured width below 0 is a contract breach of a clean state; with observation noise
        # (--disturbances noise) it happens: the onnx mode serves noisy states as they come.
        if self.args.mode != "onnx" and obs["am_bench/gripper_width"][0] < -1e-6:
            raise ValueError(f"am_bench/gripper_width: {obs['am_bench/gripper_width']} < 0")
        for key in self.images:
            if key in obs:
                v = obs[key]
                if (not isinstance(v, np.ndarray) or v.dtype != np.uint8 or v.ndim != 3
                        or v.shape[2] != 3):
                    raise TypeError(f"{key}: expected uint8 (H, W, 3), got "
                                    f"{getattr(v, 'dtype', None)} {getattr(v, 'shape', None)}")
        if not isinstance(obs["prompt"], str) or not obs["prompt"]:
            raise TypeError(f"prompt: expected a non-empty str, got {obs['prompt']!r}")
        if self.prompt is not None and obs["prompt"] != self.prompt:
            raise ValueError(f"prompt: {obs['prompt']!r}, expected {self.prompt!r}")


class Policy:
    def __init__(self, args):
        self.args = args
        self.dim = 8 if args.interface == "ee" else 8 + args.arm_joints
        self.demo = load_demo(args.demo) if args.mode == "replay" else None
        if self.demo is not None and self.demo.shape[1] != self.dim:
            raise SystemExit(f"--demo: rows of {self.demo.shape[1]} values, the interface takes {self.dim}")
        self.session = None
        if args.mode == "onnx":
            if not args.model:
                raise SystemExit("--mode onnx: name the model with --model M.onnx")
            import onnxruntime as ort
            try:
                with open(args.model + ".json") as f:
                    self.sidecar = json.load(f)
                self.session = ort.InferenceSession(args.model, providers=["CPUExecutionProvider"])
            except Exception as e:  # noqa: BLE001 - one line naming the file
                raise SystemExit(f"--model {args.model}: {e}")
            if self.sidecar.get("images"):
                raise SystemExit(f"--model {args.model}: image inputs are not served here (state-only models)")
            out = self.sidecar["output"]
            if out.get("semantics", "absolute") != "absolute" or out["dim"] != self.dim:
                raise SystemExit(f"--model {args.model}: serves absolute {self.dim}-value actions, "
                                 f"the sidecar says {out.get('semantics')} {out['dim']}")
            st = self.sidecar["state"]
            self.state_keys = st["keys"]
            self.x_mean = np.array(st.get("mean", 0.0), dtype=np.float32)
            self.x_std = np.array(st.get("std", 1.0), dtype=np.float32)
            self.a_mean = np.array(out.get("mean", 0.0), dtype=np.float32)
            self.a_std = np.array(out.get("std", 1.0), dtype=np.float32)
            self.horizon = out["chunk"]
        self.offset = parse_vector(args.offset, 3, "offset")
        self.quat = parse_vector(args.quat, 4, "quat")

    def chunk(self, obs, query, origin):
        h = self.args.horizon
        if self.session is not None:
            x = np.concatenate([obs[f"am_bench/{k}"] for k in self.state_keys]).astype(np.float32)
            x = ((x - self.x_mean) / self.x_std)[None]
            (y,) = self.session.run(None, {self.sidecar["state"]["input"]: x})
            return (y.reshape(self.horizon, self.dim) * self.a_std + self.a_mean).astype(np.float32)
        if self.demo is not None:
            s, n = self.args.stride, self.args.action_steps
            idx = [min(s * (query * n + i) + s - 1, len(self.demo) - 1) for i in range(h)]
            return self.demo[idx].astype(np.float32)
        pos_key = "am_bench/ee_pos" if self.args.interface == "ee" else "am_bench/base_pos"
        start = obs[pos_key].astype(np.float64)
        rows = []
        for i in range(h):
            f = min(1.0, (i + 1) / h)
            goal = origin + self.offset
            row = list(start + f * (goal - start)) + list(self.quat)
            if self.args.interface != "ee":
                row += list(obs["am_bench/arm_joint_pos"].astype(np.float64))
            rows.append(row + [self.args.gripper])
        return np.array(rows, dtype=np.float32)


def faulty(actions, fault):
    if fault == "wrong-shape":
        return actions[:, :-1]
    if fault == "nan":
        actions = actions.copy()
        actions[1, 0] = np.nan
        return actions
    if fault == "unnormalised":
        actions = actions.copy()
        actions[:, 3:7] *= 2.0
        return actions
    return actions


async def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000, help="0: any free port")
    p.add_argument("--mode", choices=["goto", "replay", "onnx"], default="goto")
    p.add_argument("--model", help="onnx: the model (its sidecar beside it, MODEL.json)")
    p.add_argument("--interface", choices=["ee", "base-joint"], default="ee")
    p.add_argument("--arm-joints", type=int, default=4)
    p.add_argument("--horizon", type=int, default=10, help="actions per chunk (H)")
    p.add_argument("--action-steps", type=int, default=8, help="replay: actions amstack executes per query")
    p.add_argument("--stride", type=int, default=6, help="replay: control steps per policy step (120/20)")
    p.add_argument("--offset", default="0.1,0,0.1",
                   help="goto: the goal from the first observed position, x,y,z (m)")
    p.add_argument("--quat", default="1,0,0,0", help="goto: target orientation w,x,y,z")
    p.add_argument("--gripper", type=float, default=1.0)
    p.add_argument("--demo", help="replay: an MCAP with /action, or a JSON list of rows")
    p.add_argument("--prompt", help="the prompt amstack must send")
    p.add_argument("--fault", choices=["die", "timeout", "wrong-shape", "nan", "unnormalised", "error"])
    p.add_argument("--fault-after", type=int, default=1, help="the first query (0-based) that is faulty")
    p.add_argument("--log", help="append one JSON line per request here")
    args = p.parse_args()

    contract = Contract(args)
    policy = Policy(args)
    metadata = {"server": "amstack scripts/openpi_server.py", "mode": args.mode,
                "action_dim": policy.dim,
                "horizon": policy.horizon if policy.session is not None else args.horizon}

    async def handler(websocket):
        packer = msgpack_numpy.Packer()
        await websocket.send(packer.pack(metadata))
        query = 0
        origin = None
        while True:
            try:
                obs = msgpack_numpy.unpackb(await websocket.recv())
                if args.log:
                    with open(args.log, "a") as f:
                        f.write(json.dumps({
                            "query": query,
                            "keys": {k: ([str(v.dtype), list(v.shape)] if isinstance(v, np.ndarray)
                                         else type(v).__name__) for k, v in obs.items()},
                            "state": {k: v.tolist() for k, v in obs.items()
                                      if isinstance(v, np.ndarray) and v.dtype == np.float32},
                            "prompt": obs.get("prompt"),
                        }) + "\n")
                contract.check(obs)
                if origin is None:
                    pos_key = "am_bench/ee_pos" if args.interface == "ee" else "am_bench/base_pos"
                    origin = obs[pos_key].astype(np.float64)
                fault = args.fault if query >= args.fault_after else None
                if fault == "die":
                    os._exit(3)
                if fault == "timeout":
                    await asyncio.sleep(3600)
                if fault == "error":
                    raise RuntimeError("deliberate policy failure (--fault error)")
                actions = faulty(policy.chunk(obs, query, origin), fault)
                query += 1
                await websocket.send(packer.pack({"actions": actions,
                                                  "server_timing": {"infer_ms": 0.0}}))
            except websockets.exceptions.ConnectionClosed:
                break
            except Exception:
                await websocket.send(traceback.format_exc())
                await websocket.close(code=websockets.frames.CloseCode.INTERNAL_ERROR,
                                      reason="Internal server error. Traceback included in previous frame.")
                break

    async with ws_server.serve(handler, args.host, args.port, compression=None, max_size=None) as server:
        port = server.sockets[0].getsockname()[1]
        print(f"listening on ws://{args.host}:{port}", flush=True)
        await server.serve_forever()


if __name__ == "__main__":
    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        sys.exit(0)
