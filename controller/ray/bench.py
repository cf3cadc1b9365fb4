#!/usr/bin/env python3
"""Bench: robodeploy-ray on a local cluster with 1 and 2 worker nodes (one CPU each), against
`robodeploy batch` on one machine. Prints runs per second, the overhead a distributed task adds to
the runs it carries, and what a 10 000-clip library would cost in CPU-hours by extrapolation.

Run it in a network namespace of its own, so Ray stays on 127.0.0.1:

    unshare -rn bash -c 'ip link set lo up && .local/venv/bin/python controller/ray/bench.py'
"""

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
BIN = ROOT / "target/debug/robodeploy"
VENV = ROOT / ".local/venv/bin"
CLIPS = ["robots/biped/clips/squat.csv", "robots/biped/clips/wave_and_look.csv", "robots/biped/clips/cmu_traffic_wave.csv"]
SEEDS = "0-7"
RUNS_PER_TASK = 4
PORT = 6381


def run(args, **kw):
    done = subprocess.run([str(a) for a in args], capture_output=True, text=True, cwd=ROOT, **kw)
    if done.returncode != 0:
        sys.exit(f"{args[0]} failed: {done.stdout}{done.stderr}")
    return done


def main():
    work = Path(tempfile.mkdtemp(prefix="ray-bench-"))
    mirror = work / "random.toml"
    mirror.write_text("[randomization]\nmass_scale = [0.9, 1.1]\nfriction_scale = [0.8, 1.2]\n")
    runs = len(CLIPS) * 8
    t0 = time.monotonic()
    run([BIN, "batch", "--clips", *CLIPS, "--seeds", SEEDS, "--mirror", mirror, "--jobs", "1", "--json", work / "local.jsonl"])
    local_1 = time.monotonic() - t0
    t0 = time.monotonic()
    run([BIN, "batch", "--clips", *CLIPS, "--seeds", SEEDS, "--mirror", mirror, "--jobs", "2", "--json", work / "local2.jsonl"])
    local_2 = time.monotonic() - t0
    print(f"one machine, robodeploy batch: {runs} runs, 1 job {local_1:.2f} s ({runs / local_1:.2f} runs/s), "
          f"2 jobs {local_2:.2f} s ({runs / local_2:.2f} runs/s)")
    per_run = local_1 / runs
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    common = ["--node-ip-address=127.0.0.1", "--disable-usage-stats"]
    try:
        run([VENV / "ray", "start", "--head", f"--port={PORT}", "--num-cpus=0", "--include-dashboard=false",
             f"--temp-dir=/tmp/rdbench-{os.getpid()}", *common], env=env)
        for workers in (1, 2):
            run([VENV / "ray", "start", f"--address=127.0.0.1:{PORT}", "--num-cpus=1", *common], env=env)
            out = work / f"ray-{workers}"
            t0 = time.monotonic()
            run([VENV / "robodeploy-ray", "batch", "--address", f"127.0.0.1:{PORT}", "--clips", *CLIPS, "--seeds", SEEDS,
                 "--mirror", mirror, "--out", out, "--binary", BIN, "--runs-per-task", str(RUNS_PER_TASK)], env=env)
            wall = time.monotonic() - t0
            f = json.loads((out / "figures.json").read_text())
            # What the cluster spent beyond the runs themselves: worker-seconds over one core's batch.
            overhead = (f["wall_s"] * workers - local_1) / f["tasks"]
            print(f"ray, {workers} worker{'s' if workers > 1 else ''}: {runs} runs in {f['wall_s']:.2f} s of tasks "
                  f"({runs / f['wall_s']:.2f} runs/s; {wall:.2f} s with the driver's start and bundle), "
                  f"{f['tasks']} tasks of {RUNS_PER_TASK} runs, overhead {overhead:.2f} worker-s a task "
                  f"({overhead / RUNS_PER_TASK:.2f} s a run)")
        cpu_h = 10_000 * 64 * per_run / 3600
        print(f"a 10 000-clip library × 64 seeds at {per_run:.3f} CPU-s a run (clips of these lengths): "
              f"{cpu_h:.0f} CPU-hours, plus the overhead above per task")
    finally:
        subprocess.run([str(VENV / "ray"), "stop", "--force"], capture_output=True)


if __name__ == "__main__":
    main()
