"""Reads a robodeploy MCAP with the `mcap` package (independent of the Rust writer), decodes every
message — protobuf channels through `mcap-protobuf-support` from the schemas inside the file, JSON
channels as JSON — and prints per-topic message counts, schema names and a few decoded values as
JSON.

Usage: read_mcap.py FILE.mcap [--cut]

--cut reads a file that a crash cut short with the package's stream reader, record by record up to
the cut (the indexed reader needs the footer a finished file has); `cut` in the output says
whether the file ended early.
"""
import json
import sys

from google.protobuf.json_format import MessageToDict
from mcap_protobuf.decoder import DecoderFactory
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory

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


def as_dict(value):
    """A decoded ROS 2 message (mcap_ros2's dynamic classes) as plain data."""
    if isinstance(value, list):
        return [as_dict(v) for v in value]
    fields = [f for f in dir(value) if not f.startswith("_")] if hasattr(value, "__slots__") else None
    return {f: as_dict(getattr(value, f)) for f in fields} if fields else value


def decode(schema, channel, message, protobuf=DecoderFactory(), ros2=Ros2DecoderFactory()):
    """The message as a dict: protobuf by its schema, ROS 2 CDR by its ros2msg definition, JSON as
    JSON; anything else fails."""
    if channel.message_encoding == "json":
        return json.loads(message.data)
    if channel.message_encoding == "cdr":
        return as_dict(ros2.decoder_for("cdr", schema)(message.data))
    decoder = protobuf.decoder_for(channel.message_encoding, schema)
    if decoder is None:
        raise SystemExit(f"{channel.topic}: no decoder for {channel.message_encoding} / {schema and schema.encoding}")
    return MessageToDict(decoder(message.data), preserving_proto_field_name=True)


cut = False

counts, schemas, metadata, first = {}, {}, {}, {}
modes, tf_children, scene_frames = [], set(), set()
with open(sys.argv[1], "rb") as f:
    for schema, channel, message in messages(f, "--cut" in sys.argv[2:]):
        topic = channel.topic
        counts[topic] = counts.get(topic, 0) + 1
        schemas[topic] = schema.name if schema else None
        metadata[topic] = dict(channel.metadata)
        data = decode(schema, channel, message)
        first.setdefault(topic, data)
        if topic == "/safety":
            modes.append(data["mode"])
        if topic == "/tf":
            tf_children.update(t["child_frame_id"] for t in data["transforms"])
        if topic == "/robot":
            scene_frames.update(e["frame_id"] for e in data["entities"])
first.pop("/replay", None)  # long, and the project's own
print(json.dumps(dict(counts=counts, schemas=schemas, metadata=metadata, first=first, modes=modes,
                      tf_children=sorted(tf_children), scene_frames=sorted(scene_frames), cut=cut)))
