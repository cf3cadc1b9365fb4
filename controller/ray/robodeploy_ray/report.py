"""One table and one report from a job's rows."""

from __future__ import annotations

import collections
import decimal
import json
import math
import re
import statistics
from pathlib import Path

# `robodeploy batch --csv`'s columns: the same table, in the same format, from either tool.
BATCH_COLUMNS = [
    "clip", "seed", "success", "fell", "outcome", "ticks", "played",
    "joint_rmse_deg", "root_rmse_cm", "limited_ticks", "error",
]
# Text columns, always quoted (as `batch --csv` writes them).
QUOTED = {"clip", "outcome", "error"}


def sorted_rows(rows: list[dict]) -> list[dict]:
    """Rows in (clip, seed) order, one per run."""
    return sorted(rows, key=lambda r: (r["clip"], r.get("seed", 0)))


def cell(column: str, value) -> str:
    """One value as `robodeploy batch --csv` writes it: booleans `true`/`false`, numbers at full
    precision without an exponent (`1`, `0.5`, `0.0000001`, as Rust prints them), nothing for
    none, text quoted; lists and tables as JSON."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        text = format(decimal.Decimal(repr(value)), "f")
        if "." in text:
            text = text.rstrip("0").rstrip(".")
        return "-0" if text == "0" and math.copysign(1.0, value) < 0 else text
    if isinstance(value, (list, dict)):
        value = json.dumps(value)
    text = str(value)
    return '"' + text.replace('"', '""') + '"' if column in QUOTED or isinstance(value, str) and ("," in text or '"' in text) else text


def write_table(rows: list[dict], out: Path) -> None:
    """`table.csv` (byte for byte what `robodeploy batch --csv` writes for the same runs) and
    `table.json` (every field)."""
    rows = sorted_rows(rows)
    (out / "table.json").write_text(json.dumps(rows, sort_keys=True, indent=1) + "\n")
    columns = BATCH_COLUMNS if rows and "seed" in rows[0] else sorted({k for r in rows for k in r})
    lines = [",".join(columns)]
    lines += [",".join(cell(c, r.get(c)) for c in columns) for r in rows]
    (out / "table.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")


def _cause(outcome: str) -> str:
    """The cause of a stop, without the tick and joint numbers that vary run to run."""
    text = re.sub(r" at tick \d+", "", outcome)
    return re.sub(r"\d+(\.\d+)?", "N", text)


def _spread(values: list[float]) -> str:
    if not values:
        return "-"
    v = sorted(values)
    p90 = v[min(len(v) - 1, round(0.9 * (len(v) - 1)))]
    return f"{v[0]:.2f} / {statistics.median(v):.2f} / {p90:.2f} / {v[-1]:.2f}"


def write_batch_report(rows: list[dict], out: Path, figures: dict) -> str:
    """`report.md`: success per clip, worst clips first; failure causes; RMSE distributions."""
    by_clip = collections.defaultdict(list)
    for r in rows:
        by_clip[r["clip"]].append(r)
    lines = [
        "# Batch on a Ray cluster",
        "",
        f"{len(rows)} runs of {len(by_clip)} clips; {figures.get('line', '')}",
        "",
        "| clip | runs | success | falls | joint RMSE ° min / median / p90 / max | root RMSE cm min / median / p90 / max |",
        "|---|---|---|---|---|---|",
    ]
    order = sorted(by_clip, key=lambda c: (sum(r["success"] for r in by_clip[c]) / len(by_clip[c]), c))
    for c in order:
        rs = by_clip[c]
        ok = sum(r["success"] for r in rs)
        lines.append(
            f"| {c} | {len(rs)} | {100 * ok / len(rs):.0f} % | {sum(r['fell'] for r in rs)} | "
            f"{_spread([r['joint_rmse_deg'] for r in rs if r['joint_rmse_deg'] is not None])} | "
            f"{_spread([r['root_rmse_cm'] for r in rs if r['root_rmse_cm'] is not None])} |"
        )
    causes = collections.Counter(_cause(r["outcome"]) for r in rows if not r["success"])
    lines += ["", "## Why runs failed", ""]
    lines += [f"- {n} × {cause}" for cause, n in causes.most_common()] or ["- none"]
    text = "\n".join(lines) + "\n"
    (out / "report.md").write_text(text)
    return text


def write_check_report(rows: list[dict], out: Path) -> str:
    """`report.md` of a clip-library check: the clips the robot should not play, and why."""
    bad = [r for r in rows if r.get("error") or r.get("problems")]
    lines = ["# Clip library check on a Ray cluster", "", f"{len(rows)} clips, {len(bad)} refused", ""]
    for r in sorted(bad, key=lambda r: r["clip"]):
        why = r.get("error") or "; ".join(r["problems"])
        lines.append(f"- {r['clip']}: {why}")
    lines += ["", "## Sliding and floating of the clips that pass", ""]
    lines.append("| clip | foot sliding m/s | foot floating cm | penetration ticks |")
    lines.append("|---|---|---|---|")
    for r in sorted((r for r in rows if not (r.get("error") or r.get("problems"))), key=lambda r: r["clip"]):
        q = r["quality"]
        lines.append(f"| {r['clip']} | {q['foot_sliding']:.3f} | {100 * q['foot_floating']:.1f} | {q['penetration_ticks']} |")
    text = "\n".join(lines) + "\n"
    (out / "report.md").write_text(text)
    return text
