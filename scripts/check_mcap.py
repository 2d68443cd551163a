#!/usr/bin/env python3
"""Independent check of a povins MCAP file with the official Python tools.

Usage: check_mcap.py FILE

Reads FILE with PyPI `mcap` and decodes every message with `mcap-ros2-support`'s ROS 2 decoder
(which parses the `ros2msg` schema text stored in the file), or, on a schemaless `json` channel
(the simulator's truth, `/povins/sim_truth/landmarks`), with Python's `json` (each message's
`t_ns` must be its log time, each landmark must have the documented keys), then prints one line
per topic:

    topic <name> <schema, or the message encoding without one> <message count> <first stamp, ns>

and one line per metadata record and attachment:

    metadata <name> <number of keys>
    attachment <name> <media type> <bytes>

Exits non-zero when any message fails to decode.
Install: pip install mcap mcap-ros2-support
"""
import json
import sys
from collections import OrderedDict

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def stamp_ns(msg):
    header = getattr(msg, "header", None)
    if header is None:
        return -1
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def main(argv):
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    topics = OrderedDict()
    with open(argv[1], "rb") as f:
        reader = make_reader(f)
        ros2 = DecoderFactory()
        decoders = {}
        for schema, channel, message in reader.iter_messages():
            if channel.message_encoding == "json" and schema is None:
                decoded = json.loads(message.data)
                assert decoded["t_ns"] == message.log_time, (channel.topic, message.sequence)
                for lm in decoded["landmarks"]:
                    assert set(lm) == {"id", "p_w", "last_ns", "wrong", "edge"}, lm
                    assert lm["p_w"] is None or len(lm["p_w"]) == 3, lm
                name, stamp = "json", decoded["t_ns"]
            else:
                if channel.id not in decoders:
                    decoders[channel.id] = ros2.decoder_for(channel.message_encoding, schema)
                decoder = decoders[channel.id]
                if decoder is None:
                    raise SystemExit(f"{channel.topic}: no decoder for {channel.message_encoding}")
                name, stamp = schema.name, stamp_ns(decoder(message.data))
            entry = topics.setdefault(channel.topic, [name, 0, stamp])
            entry[1] += 1
        for topic, (schema, count, first) in sorted(topics.items()):
            print(f"topic {topic} {schema} {count} {first}")
        for meta in reader.iter_metadata():
            print(f"metadata {meta.name} {len(meta.metadata)}")
        for att in reader.iter_attachments():
            print(f"attachment {att.name} {att.media_type} {len(att.data)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
