"""Reads a robodeploy MCAP with the `mcap` package (independent of the Rust writer) and prints
per-topic message counts, schema names and a few decoded values as JSON.

Usage: read_mcap.py FILE.mcap
"""
import json
import sys

from mcap.reader import make_reader

counts, schemas, metadata = {}, {}, {}
first_joint_state, modes, first_tf, tf_children = None, [], None, set()
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    for schema, channel, message in reader.iter_messages():
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
        schemas[channel.topic] = schema.name if schema else None
        metadata[channel.topic] = dict(channel.metadata)
        data = json.loads(message.data)
        if channel.topic == "/joint_state" and first_joint_state is None:
            first_joint_state = data
        if channel.topic == "/safety":
            modes.append(data["mode"])
        if channel.topic == "/tf":
            tf_children.add(data["child_frame_id"])
            if first_tf is None:
                first_tf = data
print(json.dumps(dict(counts=counts, schemas=schemas, metadata=metadata,
                      first_joint_state=first_joint_state, modes=modes, first_tf=first_tf,
                      tf_children=sorted(tf_children))))
