#!/usr/bin/env python3
"""Run `prm precompute` in parts on a Ray cluster: the plan once, N shards as Ray tasks
(retried when a worker dies), and the merge here. The result is the same bytes as
`prm precompute` on one machine with the same options.

    python3 scripts/ray_precompute.py assets/chamber.glb -o chamber.prm --shards 8 [--address auto]
        [--prm PATH] [--retries 3] [--json] [-- PRECOMPUTE OPTIONS...]

Without --address, a Ray instance is started on this machine for the run. Options after `--`
go to `prm precompute --prepare` (--preset, --seed, --atlas, ...); --require-uv1 and
--allow-overlap there are passed to the shards too, which load the level the same way. The
level and the plan go to the workers through Ray's object store and each part comes back the
same way, so the workers need the `prm` binary (--prm, or PRM_BIN, or `prm` on their PATH) but
no shared file system.

Each task reserves --threads CPUs (default 1) and runs `prm` with that many threads, so Ray
packs one shard per CPU; the plan gets --plan-threads. A task is run again (--retries) when its
worker dies or `prm` is killed by a signal; a `prm` that fails with an error (a bad option, a
damaged file) is not, and the driver stops with its message.

Test hook (one machine only: its marker is a file on the driver's disk): --kill-worker-once I
makes shard I's first attempt kill its own worker process (SIGKILL) while `prm` walks, as a
machine lost mid-shard would; Ray runs it again.
"""

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import ray

# Options of `prm precompute` that decide how the level loads, so the shards need them too.
LOAD_FLAGS = ("--require-uv1", "--allow-overlap")


class PrmCrashed(RuntimeError):
    """`prm` was killed by a signal (out of memory, a node going away): worth running again."""


class PrmFailed(RuntimeError):
    """`prm` refused or failed with an error: running it again would fail again."""


def run_prm(prm, args, cwd):
    """Run `prm ARGS` in `cwd`; its output, or an error with its stderr."""
    done = subprocess.run([prm, *args], cwd=cwd, capture_output=True, text=True)
    if done.returncode < 0:
        raise PrmCrashed(f"prm {' '.join(args)} was killed by signal {-done.returncode}")
    if done.returncode != 0:
        raise PrmFailed(f"prm {' '.join(args)} failed ({done.returncode}): {done.stderr.strip()}")
    return done.stdout


@ray.remote
def make_plan(prm, level_name, level, options):
    """The plan (`prm precompute --prepare`) of the level, as bytes."""
    with tempfile.TemporaryDirectory(prefix="prm-plan-") as d:
        with open(os.path.join(d, level_name), "wb") as f:
            f.write(level)
        run_prm(prm, ["precompute", level_name, "--prepare", "-o", "level.plan", "--json", *options], d)
        with open(os.path.join(d, "level.plan"), "rb") as f:
            return f.read()


@ray.remote
def walk_shard(prm, level_name, level, plan, index, count, load_flags, kill_marker):
    """Part `index` of `count` (`prm precompute --shard`), as bytes, and its JSON summary."""
    with tempfile.TemporaryDirectory(prefix=f"prm-shard-{index}-") as d:
        with open(os.path.join(d, level_name), "wb") as f:
            f.write(level)
        with open(os.path.join(d, "level.plan"), "wb") as f:
            f.write(plan)
        args = ["precompute", level_name, "--shard", f"{index}/{count}", "--plan", "level.plan", "-o", "part", "--json"]
        args += load_flags
        if kill_marker is not None and not os.path.exists(kill_marker):
            # The test hook: this worker dies in its first attempt, once `prm` is walking (its
            # part's temporary file exists) and before the part is done.
            child = subprocess.Popen([prm, *args], cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            seen, deadline = False, time.time() + 300
            while not seen and child.poll() is None and time.time() < deadline:
                seen = any(n.startswith(".part.tmp") for n in os.listdir(d))
                time.sleep(0.001)
            child.kill()
            mid = seen and not os.path.exists(os.path.join(d, "part"))
            with open(kill_marker, "w") as f:
                f.write("mid-walk" if mid else "after the walk")
            # A worker killed outright leaves its temporary directory behind; the test's own
            # kill removes it first, so that each run of the test does not leave one in /tmp.
            shutil.rmtree(d, ignore_errors=True)
            os.kill(os.getpid(), signal.SIGKILL)
        summary = json.loads(run_prm(prm, args, d))
        with open(os.path.join(d, "part"), "rb") as f:
            return f.read(), summary


def main():
    argv = sys.argv[1:]
    passthrough = []
    if "--" in argv:
        k = argv.index("--")
        argv, passthrough = argv[:k], argv[k + 1:]
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("level", help="the level (.glb or .gltf with its files embedded)")
    p.add_argument("-o", "--output", required=True, help="output .prm")
    p.add_argument("--shards", type=int, default=8, help="parts N (default 8)")
    p.add_argument("--address", default=None, help="Ray cluster address (default: a local instance)")
    p.add_argument("--prm", default=os.environ.get("PRM_BIN") or shutil.which("prm") or "prm",
                   help="the prm binary on the workers (default: $PRM_BIN, or prm on PATH)")
    p.add_argument("--node-ip-address", default=None,
                   help="this machine's address in the cluster (a local test cluster: 127.0.0.1)")
    p.add_argument("--threads", type=int, default=1,
                   help="CPUs each shard reserves and prm threads it runs (default 1)")
    p.add_argument("--plan-threads", type=int, default=None,
                   help="CPUs the plan reserves and its prm threads (default: --threads)")
    p.add_argument("--retries", type=int, default=3, help="times a shard is run again after a failure")
    p.add_argument("--kill-worker-once", type=int, default=None, metavar="I", help=argparse.SUPPRESS)
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    a = p.parse_args(argv)
    if not 1 <= a.shards <= 65536:
        p.error(f"--shards {a.shards}: use 1 to 65536")
    if not os.path.isfile(a.level):
        p.error(f"{a.level}: no such file")
    prm = os.path.abspath(a.prm) if os.path.sep in a.prm else a.prm
    load_flags = [f for f in passthrough if f in LOAD_FLAGS]
    if a.threads < 1 or (a.plan_threads is not None and a.plan_threads < 1):
        p.error("--threads and --plan-threads: at least 1")
    plan_threads = a.plan_threads or a.threads

    start = time.time()
    ray.init(address=a.address, _node_ip_address=a.node_ip_address, logging_level="ERROR",
             log_to_driver=False)
    with open(a.level, "rb") as f:
        level = ray.put(f.read())
    name = os.path.basename(a.level)
    retry = dict(max_retries=a.retries, retry_exceptions=[PrmCrashed])
    plan = make_plan.options(num_cpus=plan_threads, **retry).remote(
        prm, name, level, passthrough + ["--threads", str(plan_threads)])
    try:
        plan_bytes = ray.get(plan)
    except ray.exceptions.RayTaskError as e:
        ray.shutdown()
        sys.exit(f"the plan failed: {e.cause}")
    planned = time.time()
    marker = None
    tmp = tempfile.mkdtemp(prefix="prm-merge-")
    try:
        if a.kill_worker_once is not None:
            marker = os.path.join(tmp, "killed-once")
        tasks = {}
        for i in range(a.shards):
            kill = marker if i == a.kill_worker_once else None
            ref = walk_shard.options(num_cpus=a.threads, **retry).remote(
                prm, name, level, plan, i, a.shards, load_flags + ["--threads", str(a.threads)], kill)
            tasks[ref] = i
        # Each part goes to disk as it comes, and its reference is dropped.
        paths = [os.path.join(tmp, f"part-{i}") for i in range(a.shards)]
        summaries, pending = {}, list(tasks)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                i = tasks.pop(ref)
                try:
                    part, summaries[i] = ray.get(ref)
                except ray.exceptions.RayError as e:
                    sys.exit(f"shard {i}/{a.shards} failed: {getattr(e, 'cause', None) or e}")
                with open(paths[i], "wb") as f:
                    f.write(part)
                del part, ref
                if not a.json:
                    print(f"shard {i}/{a.shards} done ({len(summaries)}/{a.shards})", file=sys.stderr, flush=True)
        walked = time.time()
        with open(os.path.join(tmp, "level.plan"), "wb") as f:
            f.write(plan_bytes)
        out = os.path.abspath(a.output)
        merged = json.loads(run_prm(prm, ["merge", "--plan", "level.plan", *paths, "-o", out, "--json"], tmp))
        summary = {
            "output": a.output,
            "shards": a.shards,
            "nodes": len([n for n in ray.nodes() if n.get("Alive")]),
            "killed_worker_once": a.kill_worker_once,
            "worker_killed": open(marker).read() if marker and os.path.exists(marker) else None,
            "seconds_plan": planned - start,
            "seconds_shards": walked - planned,
            "seconds_merge": time.time() - walked,
            "seconds_total": time.time() - start,
            "shard_seconds": [summaries[i]["seconds_wall"] for i in range(a.shards)],
            "file_bytes": merged["file_bytes"],
        }
        if a.json:
            print(json.dumps(summary, indent=2))
        else:
            print(f"{a.level} -> {a.output}: {a.shards} shards on {summary['nodes']} Ray node(s), "
                  f"plan {summary['seconds_plan']:.1f} s, shards {summary['seconds_shards']:.1f} s, "
                  f"merge {summary['seconds_merge']:.1f} s, {merged['file_bytes'] / 1e6:.1f} MB")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        ray.shutdown()


if __name__ == "__main__":
    main()
