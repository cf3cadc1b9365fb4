"""Splitting a job into tasks, running them on Ray, and keeping what came back.

A task is one clip with a group of seeds (or one clip's check), sized to take a few seconds, so a
lost worker costs little and the cluster stays busy. Each finished task's rows are appended to
`results.jsonl` at once (flushed and synced): a job stopped half-way resumes from there, and no
run recorded there is done again.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import ray

# Lockstep runs on the mirror go about this many times faster than real time on one core (the
# README's batch figures); it sizes tasks before any has run.
SIMULATED_SECONDS_PER_SECOND = 20.0


@dataclasses.dataclass(frozen=True)
class Task:
    """One clip and the seeds it runs with (none for a check)."""

    clip: str  # as the user gave it
    seeds: tuple[int, ...]


def plan(clips: list[str], seeds: list[int], done: set[tuple[str, int]], runs_per_task: int) -> list[Task]:
    """The tasks still to run: every (clip, seed) not in `done`, `runs_per_task` seeds a task."""
    tasks = []
    for clip in clips:
        todo = [s for s in seeds if (clip, s) not in done]
        for k in range(0, len(todo), runs_per_task):
            tasks.append(Task(clip, tuple(todo[k : k + runs_per_task])))
    return tasks


def runs_per_task(clip_seconds: float, task_seconds: float) -> int:
    """How many runs of a clip this long fill a task of about `task_seconds`."""
    per_run = max(clip_seconds + 2.0, 1.0) / SIMULATED_SECONDS_PER_SECOND
    return max(1, int(task_seconds / per_run))


def clip_seconds(path: str) -> float:
    """A clip's length, s, from its last CSV time stamp (other formats: a guess of 10 s)."""
    p = Path(path)
    if p.suffix.lower() != ".csv":
        return 10.0
    last = None
    with open(p, encoding="utf-8", errors="replace") as f:
        for line in f:
            head = line.split(",", 1)[0].strip()
            try:
                last = float(head)
            except ValueError:
                continue
    return last if last is not None else 10.0


def _seed_range(seeds: tuple[int, ...]) -> list[str]:
    """`--seeds A-B` arguments covering `seeds` (consecutive runs of them)."""
    out, start, prev = [], seeds[0], seeds[0]
    for s in seeds[1:]:
        if s != prev + 1:
            out.append(f"{start}-{prev}")
            start = s
        prev = s
    out.append(f"{start}-{prev}")
    return out


# A worker that finds no bundle in its working directory (a worker started while the runtime
# environment is set up again after another was killed) tries again on a fresh one; a bundle
# really without its binary still fails after the retries.
@ray.remote(num_cpus=1, max_retries=3, retry_exceptions=[FileNotFoundError])
def run_batch_task(bundle: dict, task: Task) -> list[dict]:
    """Runs `robodeploy batch` for one task inside the bundle (the task's working directory);
    returns its rows, with the clip named as the user gave it."""
    rows = []
    inside = bundle["clips"][task.clip]
    for seeds in _seed_range(task.seeds):
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "rows.jsonl"
            args = [
                "bin/robodeploy", "batch",
                "--robot", bundle["robot"],
                "--policy", bundle["policy"],
                "--clips", inside,
                "--seeds", seeds,
                "--jobs", "1",
                "--json", str(out),
            ]
            if bundle["mirror"]:
                args += ["--mirror", bundle["mirror"]]
            done = subprocess.run(args, capture_output=True, text=True)
            if done.returncode != 0:
                raise RuntimeError(f"robodeploy batch {task.clip} {seeds} failed ({done.returncode}): {done.stderr.strip()}")
            for line in out.read_text().splitlines():
                row = json.loads(line)
                row["clip"] = task.clip
                rows.append(row)
    return rows


# A worker that finds no bundle in its working directory (a worker started while the runtime
# environment is set up again after another was killed) tries again on a fresh one; a bundle
# really without its binary still fails after the retries.
@ray.remote(num_cpus=1, max_retries=3, retry_exceptions=[FileNotFoundError])
def run_check_task(bundle: dict, task: Task) -> list[dict]:
    """Runs `robodeploy check` on one clip inside the bundle; returns its quality row (a clip
    the checker refuses is a result, not a failure)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "quality.json"
        args = [
            "bin/robodeploy", "check",
            "--robot", bundle["robot"],
            "--policy", bundle["policy"],
            "--clip", bundle["clips"][task.clip],
            "--json", str(out),
        ]
        done = subprocess.run(args, capture_output=True, text=True)
        if not out.is_file():
            return [{"clip": task.clip, "error": done.stderr.strip() or f"exit {done.returncode}"}]
        row = json.loads(out.read_text())
        row["clip"] = task.clip
        row["error"] = None
        return [row]


class Results:
    """`results.jsonl` in the job's folder: rows as they arrive, read back on resume."""

    def __init__(self, path: Path):
        self.path = path
        self.rows: list[dict] = []
        if path.is_file():
            for line in path.read_text().splitlines():
                if line.strip():
                    self.rows.append(json.loads(line))

    def done(self) -> set[tuple[str, int]]:
        return {(r["clip"], r.get("seed", 0)) for r in self.rows}

    def add(self, rows: list[dict]) -> None:
        with open(self.path, "a", encoding="utf-8") as f:
            for r in rows:
                f.write(json.dumps(r, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.rows.extend(rows)


def run(tasks: list[Task], remote, bundle: dict, results: Results, progress) -> dict:
    """Submits `tasks`, keeps every result as it arrives; returns timing figures."""
    t0 = time.monotonic()
    pending = {remote.remote(bundle, t): t for t in tasks}
    task_times = []
    submitted = {ref: time.monotonic() for ref in pending}
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        for ref in ready:
            pending.pop(ref)
            results.add(ray.get(ref))
            task_times.append(time.monotonic() - submitted[ref])
            progress(len(results.rows))
    return {"wall_s": time.monotonic() - t0, "tasks": len(tasks), "task_s": task_times}
