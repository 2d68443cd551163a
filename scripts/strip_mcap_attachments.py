#!/usr/bin/env python3
"""Copies an MCAP file without its attachments, with an independent writer (the Python `mcap`
package): the header's profile, every metadata record, schema, channel and message kept, chunks
zstd-compressed. For the memory figures of BENCHMARKS.md (issue 32, item 7): a simulated MCAP
without the evaluation-only `povins.sim_truth.json`, as a real recording would be.

    povins simulate --scenario handheld --seed 1 --lidar-points 1500 --duration 600 \\
        --format mcap --out /tmp/b600.mcap
    scripts/pyenv.sh target/pyenv-mcap mcap mcap   # or any Python with `pip install mcap`
    target/pyenv-mcap/bin/python scripts/strip_mcap_attachments.py /tmp/b600.mcap /tmp/s600.mcap
"""

import sys

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer


def main(src: str, dst: str) -> None:
    with open(src, "rb") as f, open(dst, "wb") as o:
        r = make_reader(f)
        h = r.get_header()
        w = Writer(o, compression=CompressionType.ZSTD)
        w.start(profile=h.profile, library=h.library)
        for m in r.iter_metadata():
            w.add_metadata(m.name, m.metadata)
        schemas, channels = {}, {}
        for schema, channel, msg in r.iter_messages(log_time_order=False):
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata
                )
            w.add_message(
                channels[channel.id], msg.log_time, msg.data, msg.publish_time, msg.sequence
            )
        w.finish()


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: strip_mcap_attachments.py SRC.mcap DST.mcap")
    main(sys.argv[1], sys.argv[2])
