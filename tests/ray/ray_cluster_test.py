#!/usr/bin/env python3
"""Integration test of scripts/ray_precompute.py on a real local Ray cluster: a head node (no
CPUs, so it runs no task) and two worker nodes of one CPU each, all on this machine
(ray.cluster_utils.Cluster: separate raylets and object stores, as on a farm). Two cases:

1. the shards run as Ray tasks and merge to the bytes `prm precompute` writes on one machine;
2. shard 1's worker process is killed (SIGKILL) half way through its first attempt: Ray runs
   the shard again and the file is still those bytes.

    PRM_BIN=target/debug/prm python3 tests/ray/ray_cluster_test.py

Prints `N passed, M failed` and exits non-zero on a failure.
"""

import json
import os
import subprocess
import sys
import tempfile
import time

# Every node and the driver on the loopback address, the test talking to nothing else: without
# this Ray swaps 127.0.0.1 for the machine's outward address (services.get_node_ip_address).
os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"

from ray.cluster_utils import Cluster  # noqa: E402 (after the environment it reads)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
PRM = os.path.abspath(os.environ.get("PRM_BIN", os.path.join(ROOT, "target", "debug", "prm")))
LEVEL = os.path.join(ROOT, "assets", "cornell.glb")
# Small enough for CI, with every part of the precompute (near, echo and far fields, groups).
OPTIONS = ["--preset", "preview", "--atlas", "128", "--paths", "64", "--seed", "5"]
SHARDS = 4
LOOPBACK = "127.0.0.1"


def driver(address, out, *extra):
    """scripts/ray_precompute.py against the cluster; its JSON summary."""
    cmd = [sys.executable, os.path.join(ROOT, "scripts", "ray_precompute.py"), LEVEL, "-o", out,
           "--shards", str(SHARDS), "--address", address, "--node-ip-address", LOOPBACK, "--prm", PRM, "--json", *extra, "--", *OPTIONS]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise AssertionError(f"driver failed ({done.returncode}): {done.stderr[-2000:]}")
    # Ray's raylets write their notes (a worker lost, a task retried) to the driver's stdout
    # too; the summary is the JSON object at its end.
    out = done.stdout
    start = 0 if out.startswith("{") else out.rindex("\n{") + 1
    summary = json.loads(out[start:])
    summary["ray_notes"] = out[:start]
    return summary


def main():
    passed, failed = 0, 0
    with tempfile.TemporaryDirectory(prefix="prm-ray-test-") as d:
        one = os.path.join(d, "one.prm")
        subprocess.run([PRM, "precompute", LEVEL, "-o", one, *OPTIONS], check=True, capture_output=True)
        with open(one, "rb") as f:
            expected = f.read()
        t = time.time()
        cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "node_ip_address": LOOPBACK})
        try:
            for _ in range(2):
                cluster.add_node(num_cpus=1, node_ip_address=LOOPBACK)
            cluster.wait_for_nodes()
            print(f"local Ray cluster up in {time.time() - t:.1f} s: a head and 2 workers", flush=True)
            cases = [("shards on two workers merge to one machine's bytes", []),
                     ("a worker killed mid-shard is retried, same bytes", ["--kill-worker-once", "1"])]
            for name, extra in cases:
                out = os.path.join(d, f"ray-{len(extra)}.prm")
                try:
                    summary = driver(cluster.address, out, *extra)
                    with open(out, "rb") as f:
                        got = f.read()
                    assert got == expected, f"{out} differs from one machine's file"
                    assert summary["nodes"] >= 3, f"{summary['nodes']} Ray nodes alive"
                    if extra:
                        killed = summary["worker_killed"]
                        assert killed == "mid-walk", f"the hook killed the worker {killed}"
                        assert "will be retried" in summary["ray_notes"], "Ray did not say it ran the shard again"
                    print(f"ok: {name} ({summary['seconds_total']:.1f} s, shards "
                          f"{', '.join(f'{s:.1f}' for s in summary['shard_seconds'])} s)", flush=True)
                    passed += 1
                except AssertionError as e:
                    print(f"FAILED: {name}: {e}", flush=True)
                    failed += 1
        finally:
            cluster.shutdown()
    print(f"{passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
