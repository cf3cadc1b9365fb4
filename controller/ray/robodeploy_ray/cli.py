"""`robodeploy-ray`: robodeploy's batch and clip check on a Ray cluster.

    robodeploy-ray batch --address HOST:PORT --clips DIR_OR_FILES... --seeds 0-63 \\
        --robot robots/biped/robot.toml --policy robots/biped/policies/reference_follower.toml \\
        --mirror RANDOM.toml --out RESULTS
    robodeploy-ray check --address HOST:PORT --clips DIR --robot ... --policy ... --out RESULTS

RESULTS gets `results.jsonl` (every run as it came back), `table.csv`/`table.json` (one row per
run, in clip and seed order: the same numbers `robodeploy batch --json` gives on one machine, bit
for bit; `table.csv` in `robodeploy batch --csv`'s format) and `report.md`. Run the same command again to resume a stopped job: runs already in
`results.jsonl` are not run again. A worker lost mid-task costs that task, which Ray runs again
elsewhere (up to 3 times).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

from . import bundle as bundle_mod
from . import jobs, report

ROOT = Path(__file__).resolve().parents[3]
CLIP_SUFFIXES = (".csv", ".npz")


def _seeds(text: str) -> list[int]:
    a, _, b = text.partition("-")
    try:
        first, last = int(a), int(b or a)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: expected FIRST-LAST, e.g. 0-63") from None
    if first < 0 or last < first or last - first >= 100_000:
        raise argparse.ArgumentTypeError(f"--seeds {text!r}: need 0 <= FIRST <= LAST, at most 100000 seeds")
    return list(range(first, last + 1))


def _clips(given: list[str]) -> list[str]:
    out = []
    for g in given:
        p = Path(g)
        if p.is_dir():
            out += sorted(str(c) for c in p.rglob("*") if c.suffix.lower() in CLIP_SUFFIXES)
        elif p.is_file():
            out.append(g)
        else:
            raise SystemExit(f"--clips {g}: no such file or folder")
    if not out:
        raise SystemExit(f"--clips {' '.join(given)}: no clips (.csv, .npz) there")
    return out


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="robodeploy-ray", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    for name, what in [("batch", "clips × seeds on the mirror"), ("check", "every clip's quality on the robot model")]:
        c = sub.add_parser(name, help=what)
        c.add_argument("--address", default="auto", help="the Ray cluster (HOST:PORT of its head; default: the one this machine is part of)")
        c.add_argument("--clips", nargs="+", required=True, help="clip files, or folders searched for .csv/.npz")
        c.add_argument("--robot", type=Path, default=ROOT / "robots/biped/robot.toml")
        c.add_argument("--policy", type=Path, default=ROOT / "robots/biped/policies/reference_follower.toml")
        c.add_argument("--out", type=Path, required=True, help="the job's folder (results, table, report)")
        c.add_argument("--binary", type=Path, default=ROOT / "target/debug/robodeploy", help="the robodeploy binary to ship")
        c.add_argument("--libs", type=Path, default=ROOT / ".local/lib", help="where libmujoco and libonnxruntime are")
        if name == "batch":
            c.add_argument("--seeds", type=_seeds, default=_seeds("0-3"), help="FIRST-LAST (default 0-3)")
            c.add_argument("--mirror", type=Path, help="mirror settings (randomisation, faults), TOML")
            c.add_argument("--task-seconds", type=float, default=5.0, help="about how long a task runs (default 5)")
            c.add_argument("--runs-per-task", type=int, help="runs per task (default: from --task-seconds and each clip's length)")
    return p


def _job_id(args, clips: list[str]) -> str:
    """What makes two invocations the same job (a resume), or not."""
    h = hashlib.sha256()
    for part in [args.command, args.robot, args.policy, *clips, getattr(args, "mirror", None)]:
        h.update(str(part).encode())
        if part is not None and Path(str(part)).is_file():
            h.update(Path(str(part)).read_bytes())
    h.update(json.dumps(getattr(args, "seeds", [])).encode())
    return h.hexdigest()[:16]


def main(argv: list[str] | None = None) -> int:
    import ray

    args = _parser().parse_args(argv)
    for flag, path in [("--robot", args.robot), ("--policy", args.policy), ("--mirror", getattr(args, "mirror", None))]:
        if path is not None and not path.is_file():
            raise SystemExit(f"{flag} {path}: no such file")
    clips = _clips(args.clips)
    args.out.mkdir(parents=True, exist_ok=True)
    job = {"id": _job_id(args, clips), "command": args.command, "clips": clips}
    job_file = args.out / "job.json"
    if job_file.is_file() and json.loads(job_file.read_text())["id"] != job["id"]:
        raise SystemExit(f"{args.out} holds another job's results (job.json): give another --out, or remove it")
    job_file.write_text(json.dumps(job, indent=1) + "\n")
    results = jobs.Results(args.out / "results.jsonl")
    if args.command == "batch":
        wanted = {(c, s) for c in clips for s in args.seeds}
    else:
        wanted = {(c, 0) for c in clips}
    done = results.done() & wanted
    if done:
        print(f"resuming: {len(done)} of {len(wanted)} runs already in {results.path}", flush=True)
    b = bundle_mod.make(
        args.binary, args.libs, args.robot, args.policy, clips,
        getattr(args, "mirror", None), args.out / ".bundle",
    )
    ray.init(
        address=args.address,
        runtime_env={"working_dir": str(b.root)},
        logging_level="ERROR",
        log_to_driver=False,
    )
    cpus = int(ray.cluster_resources().get("CPU", 0))
    print(f"ray: {cpus} CPUs in the cluster; bundle {b.root.name}", flush=True)
    spec = {"robot": b.robot, "policy": b.policy, "clips": b.clips, "mirror": b.mirror}
    if args.command == "batch":
        tasks = []
        for c in clips:
            n = args.runs_per_task or jobs.runs_per_task(jobs.clip_seconds(c), args.task_seconds)
            tasks += jobs.plan([c], args.seeds, done, n)
        remote = jobs.run_batch_task
    else:
        tasks = jobs.plan(clips, [0], done, 1)
        remote = jobs.run_check_task
    total = len(wanted)
    print(f"{len(tasks)} tasks for {total - len(done)} runs", flush=True)
    figures = jobs.run(tasks, remote, spec, results, lambda n: print(f"{min(n, total)}/{total} runs done", flush=True))
    rows = [r for r in results.rows if (r["clip"], r.get("seed", 0)) in wanted]
    report.write_table(rows, args.out)
    runs = len(rows) - len(done)
    rate = runs / figures["wall_s"] if figures["wall_s"] > 0 else 0.0
    figures["line"] = f"{runs} runs in this invocation in {figures['wall_s']:.1f} s on {cpus} CPUs ({rate:.2f} runs/s)"
    text = report.write_batch_report(rows, args.out, figures) if args.command == "batch" else report.write_check_report(rows, args.out)
    (args.out / "figures.json").write_text(json.dumps({k: v for k, v in figures.items()}, indent=1) + "\n")
    print(text, flush=True)
    print(f"table: {args.out / 'table.csv'}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
