"""Reads a robodeploy MCAP with the `mcap` package (independent of the Rust writer) and prints
per-topic message counts, schema names and a few decoded values as JSON.

Usage: read_mcap.py FILE.mcap [--cut]

--cut reads a file that a crash cut short with the package's stream reader, record by record up to
the cut (the indexed reader needs the footer a finished file has); `cut` in the output says
whether the file ended early.
"""
import json
import sys

from mcap.exceptions import EndOfFile, RecordLengthLimitExceeded
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader


def messages(f, cut_ok):
    """(schema, channel, message) in file order; with `cut_ok`, stops quietly at a cut."""
    if not cut_ok:
        yield from make_reader(f).iter_messages()
        return
    schemas_by_id, channels_by_id = {}, {}
    try:
        for record in StreamReader(f).records:
            if isinstance(record, Schema):
                schemas_by_id[record.id] = record
            elif isinstance(record, Channel):
                channels_by_id[record.id] = record
            elif isinstance(record, Message):
                channel = channels_by_id[record.channel_id]
                yield schemas_by_id.get(channel.schema_id), channel, record
    except (EndOfFile, RecordLengthLimitExceeded) as e:
        # The writer streams a chunk behind a length of all ones and fills it in when the chunk
        # is done: a crash leaves that placeholder, which is a cut like any other.
        if isinstance(e, RecordLengthLimitExceeded) and f"length {2**64 - 1} " not in str(e):
            raise
        global cut
        cut = True


cut = False

counts, schemas, metadata = {}, {}, {}
first_joint_state, modes, first_tf, tf_children = None, [], None, set()
with open(sys.argv[1], "rb") as f:
    for schema, channel, message in messages(f, "--cut" in sys.argv[2:]):
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
                      tf_children=sorted(tf_children), cut=cut)))
