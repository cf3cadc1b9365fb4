#!/usr/bin/env python3
"""Write rd-biped's squat clip (robots/biped/clips/squat.csv) in two motion-file layouts that other
tools use, as FIXTURES for the clip loaders' tests — not motions of our own making beyond the squat:

  squat_beyondmimic.npz          the motion NPZ of BeyondMimic / mjlab's tracking task: `fps`,
  squat_beyondmimic.motion.toml  `joint_pos`/`joint_vel` (T x J, no joint names: the sidecar names
                                 them), `body_pos_w`/`body_quat_w` (T x B x 3/4, quaternion w x y z)
                                 and `body_lin_vel_w`/`body_ang_vel_w`. Body 0 is the root (pelvis);
                                 bodies 1 and 2 are placeholders 0.1 m above and below it (the
                                 loaders read the root only).
  squat_lafan1.csv               the headerless CSV of the LAFAN1 humanoid retargets: per row root
  squat_lafan1.motion.toml       x y z, root quaternion x y z w, then the joints; the sidecar gives
                                 the frame rate and the joint columns.

Usage: gen_motion_fixtures.py [OUT_DIR]   (default: tests/fixtures/motion)
"""
import csv
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
CLIP = ROOT / "robots/biped/clips/squat.csv"


def read_clip():
    rows = [r for r in csv.reader(l for l in CLIP.read_text().splitlines() if not l.startswith("#"))]
    header, data = rows[0], np.array([[float(x) for x in r] for r in rows[1:]])
    return header[8:], data[:, 0], data[:, 1:4], data[:, 4:8], data[:, 8:]


def main():
    out = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "tests/fixtures/motion"
    out.mkdir(parents=True, exist_ok=True)
    joints, times, pos, quat_wxyz, q = read_clip()
    fps = 1.0 / float(np.mean(np.diff(times)))
    fps = round(fps)
    names = "[" + ", ".join(f'"{j}"' for j in joints) + "]"

    # BeyondMimic / mjlab motion NPZ.
    t = len(times)
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1], [0.0, 0.0, -0.1]])
    body_pos = pos[:, None, :] + offsets[None, :, :]
    body_quat = np.repeat(quat_wxyz[:, None, :], 3, axis=1)
    vel = np.gradient(pos, 1.0 / fps, axis=0)
    np.savez(
        out / "squat_beyondmimic.npz",
        fps=np.array([fps], dtype=np.float64),
        joint_pos=q.astype(np.float32),
        joint_vel=np.gradient(q, 1.0 / fps, axis=0).astype(np.float32),
        body_pos_w=body_pos.astype(np.float32),
        body_quat_w=body_quat.astype(np.float32),
        body_lin_vel_w=np.repeat(vel[:, None, :], 3, axis=1).astype(np.float32),
        body_ang_vel_w=np.zeros((t, 3, 3), dtype=np.float32),
    )
    (out / "squat_beyondmimic.motion.toml").write_text(
        "# FIXTURE written by scripts/gen_motion_fixtures.py from robots/biped/clips/squat.csv:\n"
        "# a BeyondMimic/mjlab motion NPZ names no joints; this sidecar does.\n"
        f"joints = {names}\n"
        "root_body = 0\n"
    )

    # LAFAN1-style headerless CSV: root x y z, quaternion x y z w, joints.
    quat_xyzw = quat_wxyz[:, [1, 2, 3, 0]]
    rows = np.hstack([pos, quat_xyzw, q])
    np.savetxt(out / "squat_lafan1.csv", rows, delimiter=",", fmt="%.6f")
    (out / "squat_lafan1.motion.toml").write_text(
        "# FIXTURE written by scripts/gen_motion_fixtures.py from robots/biped/clips/squat.csv:\n"
        "# headerless rows of root x y z, root quaternion x y z w, joints (the LAFAN1 retarget layout).\n"
        f"fps = {fps}.0\n"
        'quaternion = "xyzw"\n'
        f"joints = {names}\n"
    )
    print(f"wrote {out} ({t} frames at {fps} fps)")


if __name__ == "__main__":
    main()
