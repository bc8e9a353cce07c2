#!/usr/bin/env python3
"""Ray driver of `amstack sweep --engine ray[:ADDRESS]` (shipped inside the amstack binary,
which writes it next to the sweep's plan and runs it with the Python of scripts/setup-ray.sh).

Each shard of each cell is one Ray task of one CPU. The task runs
`amstack bench <cell flags> --shard I/N --out <temp> --jobs 1` on whichever worker Ray picks
and returns the part's files (part.json and the MCAP logs) through Ray's object store, so the
workers need no shared folder for results. The driver writes the parts under the plan's
`parts/<cell>/<I>/` and, once every shard of a cell is in, runs `amstack bench merge` into the
cell's folder, which then holds exactly what the local engine writes.

What the workers need: the amstack binary at the plan's path (the same path on every node:
a shared folder, or the same install on each node) and the vehicle files a cell names. On a
single machine (the local test) that holds trivially.

A worker that dies (its process killed, its node lost) has its task retried by Ray
(max_retries); an amstack failure (bad input, a crashed rollout) is not retried: the driver
stops and names it. The plan's `kill_once` ("CELL:I") is a test hook: the first attempt of
that shard kills its own worker process with SIGKILL once amstack has started.

Usage: python ray_sweep.py --plan OUT/ray-plan.json [--address HOST:PORT]
"""

import argparse
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time


def say(message):
    print(f"ray-sweep: {message}", file=sys.stderr, flush=True)


def run_shard(amstack, bench, index, count, kill_marker):
    """One shard of one cell, on a Ray worker: the part's files, by relative path."""
    import ray

    with tempfile.TemporaryDirectory(prefix="amstack-shard-") as tmp:
        out = os.path.join(tmp, "part")
        command = [amstack, "bench", *bench, "--shard", f"{index}/{count}",
                   "--out", out, "--jobs", "1"]
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        if kill_marker is not None and not os.path.exists(kill_marker):
            with open(kill_marker, "w") as f:
                f.write(f"killed worker pid {os.getpid()} running shard {index}/{count}\n")
            time.sleep(0.5)
            proc.kill()
            proc.wait()
            shutil.rmtree(tmp, ignore_errors=True)  # a real dead worker would leave it
            os.kill(os.getpid(), signal.SIGKILL)
        stdout, stderr = proc.communicate()
        if proc.returncode != 0:
            last = (stderr.strip().splitlines() or ["(no message)"])[-1]
            raise RuntimeError(f"amstack bench --shard {index}/{count} exited "
                               f"{proc.returncode}: {last}")
        files = {}
        for root, _, names in os.walk(out):
            for name in names:
                path = os.path.join(root, name)
                with open(path, "rb") as f:
                    files[os.path.relpath(path, out)] = f.read()
        return {"node": ray.get_runtime_context().get_node_id()[:8], "pid": os.getpid(),
                "files": files}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--plan", required=True, help="the plan written by amstack sweep")
    parser.add_argument("--address", help="a Ray cluster (HOST:PORT); default: start one here")
    args = parser.parse_args()
    with open(args.plan) as f:
        plan = json.load(f)

    import ray

    started = time.monotonic()
    ray.init(address=args.address, include_dashboard=False, logging_level=logging.WARNING)
    say(f"Ray {ray.__version__}: {int(ray.cluster_resources().get('CPU', 0))} CPU(s) on "
        f"{len(ray.nodes())} node(s)")
    task = ray.remote(num_cpus=1, max_retries=3)(run_shard)

    amstack, count = plan["amstack"], plan["shards"]
    kill = plan.get("kill_once")
    marker = os.path.join(os.path.dirname(os.path.abspath(args.plan)), "kill-once.done")
    pending = {}
    for cell in plan["cells"]:
        for index in range(count):
            hook = marker if kill == f"{cell['name']}:{index}" else None
            ref = task.remote(amstack, cell["bench"], index, count, hook)
            pending[ref] = (cell, index)
    total = len(pending)
    done_per_cell = {}
    finished = 0
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        ref = ready[0]
        cell, index = pending.pop(ref)
        try:
            result = ray.get(ref)
        except Exception as e:  # the task's own error, after Ray's retries of dead workers
            say(f"cell {cell['name']} shard {index}/{count} failed: {e}")
            return 1
        part = os.path.join(plan["parts"], cell["name"], str(index))
        for rel, data in result["files"].items():
            path = os.path.join(part, rel)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            with open(path, "wb") as f:
                f.write(data)
        finished += 1
        say(f"[{finished}/{total}] cell {cell['name']} shard {index}/{count} done on "
            f"node {result['node']} (worker pid {result['pid']})")
        done_per_cell[cell["name"]] = done_per_cell.get(cell["name"], 0) + 1
        if done_per_cell[cell["name"]] == count:
            parts = [os.path.join(plan["parts"], cell["name"], str(i)) for i in range(count)]
            merge = [amstack, "bench", "merge", *parts, "--out", cell["dir"]]
            proc = subprocess.run(merge, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True)
            if proc.returncode != 0:
                say(f"cell {cell['name']}: merge failed: {proc.stderr.strip()}")
                return 1
            say(f"cell {cell['name']}: {count} shard(s) merged into {cell['dir']}")
    if kill is not None:
        say("kill-once: " + (open(marker).read().strip() if os.path.exists(marker)
                             else "no task matched " + kill))
    say(f"{total} shard(s) of {len(plan['cells'])} cell(s) in "
        f"{time.monotonic() - started:.1f} s")
    ray.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
