"""Imports a robodeploy MCAP with Rerun's own MCAP importer (rerun-sdk, `rerun.chunk.McapReader`:
the decoders the Rerun viewer runs on a dropped file) and prints, as JSON, what Rerun made of it:
rows per entity, the archetypes it recognised, the frames its Transform3D rows connect, the scalar
series it can plot from the typed joint states, the robot's geometry it built from the URDF on
/robot_description (link frames and shapes), and the joint positions it plots by name from ROS 2's
/joint_states, checked value for value against /joint_state at the same log time.

Usage: rerun_import.py FILE.mcap
"""
import json
import math
import sys

from rerun.chunk import McapReader

rows, components, frames = {}, {}, set()
positions = {}  # joint name -> positions over time
by_time = {}  # log time -> {joint name: position}, from /joint_state
urdf_frames, urdf_shapes = set(), set()
series = dict(names=None, rows=0)
series_rows = []  # (log time, values) of /joint_states/position
for chunk in McapReader(sys.argv[1]).stream():
    batch = chunk.to_record_batch()
    path = chunk.entity_path
    names = [n for n in batch.schema.names if not n.startswith(("rerun.controls", "message_", "Mcap"))]
    components.setdefault(path, set()).update(names)
    if "Transform3D:child_frame" in batch.schema.names:
        rows[path] = rows.get(path, 0) + batch.num_rows
        for parent, child in zip(batch.column("Transform3D:parent_frame").to_pylist(),
                                 batch.column("Transform3D:child_frame").to_pylist()):
            frames.add((parent[0] if isinstance(parent, list) else parent,
                        child[0] if isinstance(child, list) else child))
    if "/visual_geometries/" in path:
        urdf_shapes.update(n.split(":")[0] for n in names if n.endswith(("half_sizes", "radii", "vertex_positions")))
        if "CoordinateFrame:frame" in batch.schema.names:
            for frame in batch.column("CoordinateFrame:frame").to_pylist():
                if frame:
                    urdf_frames.add(frame[0] if isinstance(frame, list) else frame)
    if path == "/joint_states/position":
        times = batch.column("message_log_time").to_pylist()
        if series["names"] is None:
            series["names"] = next((n for n in batch.column("SeriesLines:names").to_pylist() if n), None)
        for t, values in zip(times, batch.column("Scalars:scalars").to_pylist()):
            series_rows.append((t, values))
    column = next((n for n in names if n.endswith(":message")), None)
    if column is None:
        continue
    rows[path] = rows.get(path, 0) + batch.num_rows
    if path == "/joint_state":
        for t, message in zip(batch.column("message_log_time").to_pylist(), batch.column(column).to_pylist()):
            for m in message:
                for joint in m["joints"]:
                    positions.setdefault(joint["name"], []).append(joint["position"])
                    by_time.setdefault(t, {})[joint["name"]] = joint["position"]

series["rows"] = len(series_rows)
series["agree"] = bool(series_rows) and series["names"] is not None and all(
    t in by_time and [by_time[t][n] for n in series["names"]] == list(values) for t, values in series_rows)

print(json.dumps(dict(
    rows=rows,
    components={k: sorted(v) for k, v in components.items()},
    frames=sorted(frames),
    joints=sorted(positions),
    samples=min((len(v) for v in positions.values()), default=0),
    finite=all(math.isfinite(x) for v in positions.values() for x in v),
    urdf_frames=sorted(urdf_frames),
    urdf_shapes=sorted(urdf_shapes),
    series=series,
)))
