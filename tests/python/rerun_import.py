"""Imports a robodeploy MCAP with Rerun's own MCAP importer (rerun-sdk, `rerun.chunk.McapReader`:
the decoders the Rerun viewer runs on a dropped file) and prints, as JSON, what Rerun made of it:
rows per entity, the archetypes it recognised, the frames its Transform3D rows connect, and the
scalar series it can plot from the typed joint states.

Usage: rerun_import.py FILE.mcap
"""
import json
import math
import sys

from rerun.chunk import McapReader

rows, components, frames = {}, {}, set()
positions = {}  # joint name -> positions over time
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
    column = next((n for n in names if n.endswith(":message")), None)
    if column is None:
        continue
    rows[path] = rows.get(path, 0) + batch.num_rows
    if path == "/joint_state":
        for message in batch.column(column).to_pylist():
            for m in message:
                for joint in m["joints"]:
                    positions.setdefault(joint["name"], []).append(joint["position"])

print(json.dumps(dict(
    rows=rows,
    components={k: sorted(v) for k, v in components.items()},
    frames=sorted(frames),
    joints=sorted(positions),
    samples=min((len(v) for v in positions.values()), default=0),
    finite=all(math.isfinite(x) for v in positions.values() for x in v),
)))
