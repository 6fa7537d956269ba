"""Copies an op3dsg MCAP recording with the independent PyPI `mcap` reader and writer, giving the
copy's `op3dsg.recorder` metadata the drop counts a recorder that fell behind would have written,
for the cross-process tests (tests/tests/it/record_daemon.rs):

    .venv/bin/python tests/python/mcap_set_drops.py IN OUT KEY=VALUE...

Every schema, channel, message and other metadata record is copied as it is, in the recorder's
order (the profile before the messages, `op3dsg.recorder` after them); in `op3dsg.recorder`
each KEY is set to VALUE (e.g. `/camera/colour.dropped=3 dropped_total=3`).
"""

import sys

from mcap.reader import make_reader
from mcap.writer import Writer


def main():
    source, target, *pairs = sys.argv[1:]
    changes = dict(pair.split("=", 1) for pair in pairs)
    with open(source, "rb") as f_in, open(target, "wb") as f_out:
        reader = make_reader(f_in)
        header = reader.get_header()
        writer = Writer(f_out)
        writer.start(profile=header.profile, library=header.library)
        # Metadata where the recorder puts it: the profile (and any other record) before the
        # messages, where a replay reads it; op3dsg.recorder after them, as a finished file has it.
        metadata = [(record.name, dict(record.metadata)) for record in reader.iter_metadata()]
        for name, entries in metadata:
            if name != "op3dsg.recorder":
                writer.add_metadata(name, entries)
        f_in.seek(0)
        reader = make_reader(f_in)
        schema_ids, channel_ids = {}, {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schema_ids:
                schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channel_ids:
                channel_ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schema_ids.get(channel.schema_id, 0), channel.metadata
                )
            writer.add_message(
                channel_ids[channel.id], message.log_time, message.data, message.publish_time, message.sequence
            )
        for name, entries in metadata:
            if name == "op3dsg.recorder":
                entries.update(changes)
                writer.add_metadata(name, entries)
        writer.finish()


if __name__ == "__main__":
    sys.exit(main())
