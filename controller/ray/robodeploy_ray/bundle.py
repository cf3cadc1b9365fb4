"""The bundle a job ships to its workers: everything a run reads, in one folder Ray uploads once.

    bin/robodeploy          the binary (debug info stripped when `strip` is there: smaller upload)
    lib/                    libmujoco and libonnxruntime (the binary looks beside itself first)
    robot/                  the robot.toml's folder (MJCF, meshes, calibration.toml)
    policy/                 the policy manifest's folder (manifest, ONNX)
    clips/K-NAME            each clip, with its `.motion.toml` sidecar when it has one
    mirror.toml             the mirror settings, when given

Paths inside are relative, so the bundle runs wherever Ray unpacks it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

NATIVE_LIBS = ("libmujoco.so.3.17.0", "libonnxruntime.so.1.31.1")


@dataclasses.dataclass
class Bundle:
    """A staged bundle and where each input sits inside it."""

    root: Path
    robot: str
    policy: str
    clips: dict[str, str]  # as given by the user → path inside the bundle
    mirror: str | None


def _copy_tree(src: Path, dst: Path) -> None:
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.mcap", "out"))


def _digest(paths: list[Path]) -> str:
    h = hashlib.sha256()
    for p in sorted(paths):
        h.update(str(p).encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


def make(
    binary: Path,
    libs: Path,
    robot: Path,
    policy: Path,
    clips: list[str],
    mirror: Path | None,
    staging: Path,
) -> Bundle:
    """Stages a bundle under `staging` (reused when its inputs are unchanged)."""
    for lib in NATIVE_LIBS:
        if not (libs / lib).is_file():
            raise SystemExit(f"{libs / lib} is missing: run scripts/setup (or pass --libs)")
    if not binary.is_file():
        raise SystemExit(f"{binary}: no robodeploy binary there (build it: cargo build -p robodeploy)")
    inputs = [binary, *(libs / lib for lib in NATIVE_LIBS), robot, policy, *(Path(c) for c in clips)]
    if mirror is not None:
        inputs.append(mirror)
    root = staging / f"bundle-{_digest(inputs)}"
    clip_paths = {c: f"clips/{k}-{Path(c).name}" for k, c in enumerate(clips)}
    bundle = Bundle(
        root=root,
        robot=f"robot/{robot.name}",
        policy=f"policy/{policy.name}",
        clips=clip_paths,
        mirror="mirror.toml" if mirror is not None else None,
    )
    if (root / ".complete").exists():
        return bundle
    partial = root.with_name(root.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    (partial / "bin").mkdir(parents=True)
    (partial / "lib").mkdir()
    (partial / "clips").mkdir()
    shutil.copy2(binary, partial / "bin" / "robodeploy")
    if shutil.which("strip"):
        subprocess.run(["strip", "--strip-debug", str(partial / "bin" / "robodeploy")], check=False)
    for lib in NATIVE_LIBS:
        shutil.copy2(libs / lib, partial / "lib" / lib)
    _copy_tree(robot.parent, partial / "robot")
    _copy_tree(policy.parent, partial / "policy")
    for given, inside in clip_paths.items():
        src = Path(given)
        shutil.copy2(src, partial / inside)
        sidecar = src.with_name(src.stem + ".motion.toml")
        if sidecar.is_file():
            shutil.copy2(sidecar, (partial / inside).with_name(Path(inside).stem + ".motion.toml"))
    if mirror is not None:
        shutil.copy2(mirror, partial / "mirror.toml")
    (partial / ".complete").write_text("")
    shutil.rmtree(root, ignore_errors=True)
    os.replace(partial, root)
    return bundle
