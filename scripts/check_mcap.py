#!/usr/bin/env python3
"""Independent check of a povins MCAP file with the official Python tools.

Usage: check_mcap.py FILE

Reads FILE with PyPI `mcap` and decodes every message with `mcap-ros2-support`'s ROS 2 decoder
(which parses the `ros2msg` schema text stored in the file), then prints one line per topic:

    topic <name> <schema> <message count> <first header stamp, ns>

and one line per metadata record and attachment:

    metadata <name> <number of keys>
    attachment <name> <media type> <bytes>

Exits non-zero when any message fails to decode.
Install: pip install mcap mcap-ros2-support
"""
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
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _message, decoded in reader.iter_decoded_messages():
            entry = topics.setdefault(channel.topic, [schema.name, 0, stamp_ns(decoded)])
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
