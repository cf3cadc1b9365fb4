#!/usr/bin/env python3
"""robodeploy-ray on a local Ray cluster, checked against robodeploy batch on one machine.

Run inside a network namespace of its own (the Rust test starts it with `unshare -rn`): only the
loopback interface exists, so every port Ray opens is on 127.0.0.1. Starts a head (no CPUs) and two
worker nodes (one CPU each), then:

1. the distributed batch of 3 clips × 4 seeds, one worker process SIGKILLed in the middle of a task:
   the task runs again, the table is complete and identical, number for number, to `robodeploy
   batch --json` on this machine;
2. the driver SIGKILLed after some runs were written, then started again: it resumes, runs only
   what is missing, and the table is again identical;
3. the clip-library check agrees with `robodeploy check --json` clip by clip.

Prints one JSON line of figures; exits non-zero with the reason on any failure. Always stops Ray.

    ray_cluster_check.py --binary target/debug/robodeploy --work DIR
"""

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
VENV_BIN = ROOT / ".local/venv/bin"
CLIPS = ["robots/biped/clips/cmu_traffic_wave.csv", "robots/biped/clips/squat.csv", "robots/biped/clips/wave_and_look.csv"]
MIRROR = "[randomization]\nmass_scale = [0.9, 1.1]\nfriction_scale = [0.8, 1.2]\nstrength_scale = [0.9, 1.0]\n"
PORT = 6379


def fail(message):
    print(f"FAIL: {message}", file=sys.stderr, flush=True)
    sys.exit(1)


def sh(args, **kw):
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, **kw)


def ray(*args):
    done = sh([VENV_BIN / "ray", *args], env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"})
    if done.returncode != 0:
        fail(f"ray {' '.join(args)}: {done.stderr[-2000:]}")


def start_cluster(temp: Path):
    common = ["--node-ip-address=127.0.0.1", "--disable-usage-stats"]
    ray("start", "--head", f"--port={PORT}", "--num-cpus=0", "--include-dashboard=false", f"--temp-dir={temp}", *common)
    for _ in range(2):
        ray("start", f"--address=127.0.0.1:{PORT}", "--num-cpus=1", *common)


def driver(args, out: Path, extra=()):
    cmd = [
        VENV_BIN / "robodeploy-ray", "batch", "--address", f"127.0.0.1:{PORT}",
        "--clips", *CLIPS, "--seeds", "0-3", "--mirror", args.mirror, "--out", out,
        "--binary", args.binary, *extra,
    ]
    return subprocess.Popen([str(c) for c in cmd], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def rows_of(path: Path):
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def keyed(rows):
    return {(r["clip"], r["seed"]): r for r in rows}


def robodeploy_children():
    """(pid, parent pid) of every robodeploy process started by a Ray worker."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().split(b"\0")
            stat = (d / "stat").read_text()
        except OSError:
            continue
        if cmd and cmd[0].endswith(b"bin/robodeploy") and b"batch" in cmd:
            ppid = int(stat.rsplit(")", 1)[1].split()[1])
            out.append((int(d.name), ppid))
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--binary", required=True)
    p.add_argument("--work", type=Path, required=True)
    args = p.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    args.mirror = args.work / "random.toml"
    args.mirror.write_text(MIRROR)
    figures = {}
    temp = Path(f"/tmp/rdray-{os.getpid()}")  # short: Ray's unix sockets live in it
    try:
        t0 = time.monotonic()
        start_cluster(temp)
        figures["cluster_start_s"] = round(time.monotonic() - t0, 2)

        # The reference: one machine.
        local = args.work / "local.jsonl"
        local_csv = args.work / "local.csv"
        t0 = time.monotonic()
        done = sh([args.binary, "batch", "--clips", *CLIPS, "--seeds", "0-3", "--mirror", args.mirror, "--jobs", "2", "--json", local, "--csv", local_csv], cwd=ROOT)
        if done.returncode != 0:
            fail(f"local batch: {done.stderr}")
        figures["local_batch_s"] = round(time.monotonic() - t0, 2)
        want = keyed(rows_of(local))
        if len(want) != 12:
            fail(f"local batch wrote {len(want)} rows")

        # 1. A worker killed mid-task.
        out1 = args.work / "killed-worker"
        t0 = time.monotonic()
        d = driver(args, out1, ["--runs-per-task", "4"])
        killed = None
        while d.poll() is None and killed is None:
            for pid, ppid in robodeploy_children():
                os.kill(ppid, signal.SIGKILL)
                killed = (pid, ppid)
                break
            time.sleep(0.005)
        text, _ = d.communicate(timeout=300)
        figures["distributed_batch_s"] = round(time.monotonic() - t0, 2)
        if d.returncode != 0:
            fail(f"driver after a killed worker: exit {d.returncode}\n{text}")
        if killed is None:
            fail(f"no task was caught running to kill its worker:\n{text}")
        got = rows_of(out1 / "results.jsonl")
        if len(got) != 12 or keyed(got) != want:
            fail(f"after the killed worker: {len(got)} rows; differ from the local batch: "
                 f"{[k for k in want if keyed(got).get(k) != want[k]]}")
        table = json.loads((out1 / "table.json").read_text())
        if keyed(table) != want:
            fail("table.json differs from the local batch")
        # One CSV format: the cluster's table.csv is the local `batch --csv`, line for line.
        ours, theirs = (p.read_text().splitlines() for p in (out1 / "table.csv", local_csv))
        if ours[0] != theirs[0] or sorted(ours[1:]) != sorted(theirs[1:]):
            fail(f"table.csv differs from `batch --csv`:\n{chr(10).join(ours[:3])}\nagainst\n{chr(10).join(theirs[:3])}")
        figures["killed_worker_pid"] = killed[1]

        # 2. The driver stopped half-way, then resumed.
        out2 = args.work / "resumed"
        d = driver(args, out2, ["--runs-per-task", "1"])
        results = out2 / "results.jsonl"
        while d.poll() is None and not (results.is_file() and len(rows_of(results)) >= 4):
            time.sleep(0.005)
        d.kill()
        d.communicate()
        before = len(rows_of(results))
        if before >= 12:
            fail("the driver finished before it could be stopped half-way")
        d = driver(args, out2, ["--runs-per-task", "1"])
        text, _ = d.communicate(timeout=300)
        if d.returncode != 0:
            fail(f"resumed driver: exit {d.returncode}\n{text}")
        if f"resuming: {before} of 12 runs already" not in text:
            fail(f"the second driver did not resume from {before} runs:\n{text}")
        got = rows_of(results)
        if len(got) != 12:
            fail(f"after the resume results.jsonl has {len(got)} rows (a run done twice, or lost)")
        if keyed(got) != want:
            fail("the resumed job's rows differ from the local batch")
        figures["resumed_after"] = before

        # 3. The clip library's quality, distributed.
        out3 = args.work / "check"
        done = sh([VENV_BIN / "robodeploy-ray", "check", "--address", f"127.0.0.1:{PORT}", "--clips", "robots/biped/clips",
                   "--out", out3, "--binary", args.binary], cwd=ROOT)
        if done.returncode != 0:
            fail(f"check: {done.stdout}{done.stderr}")
        checked = {r["clip"]: r for r in json.loads((out3 / "table.json").read_text())}
        if sorted(checked) != CLIPS:
            fail(f"check covered {sorted(checked)}")
        for clip in CLIPS:
            q = args.work / "q.json"
            sh([args.binary, "check", "--clip", clip, "--json", q], cwd=ROOT)
            mine = json.loads(q.read_text())
            if mine["problems"] != checked[clip]["problems"] or mine["quality"] != checked[clip]["quality"]:
                fail(f"{clip}: distributed check differs from the local one")
        figures["check_refused"] = sum(1 for r in checked.values() if r["problems"])
    finally:
        sh([VENV_BIN / "ray", "stop", "--force"])
        # Ray's session logs and object spill (~110 MB a run): nothing a later run reads.
        shutil.rmtree(temp, ignore_errors=True)
    print(json.dumps(figures), flush=True)


if __name__ == "__main__":
    main()
