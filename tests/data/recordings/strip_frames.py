"""Copies an MCAP recording without its frames and viewing channels: what
made v1_run.mcap from a full recording (see README.md)."""
import sys

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

DROPPED = {"frames"}

source, target = sys.argv[1], sys.argv[2]
with open(source, "rb") as f_in, open(target, "wb") as f_out:
    reader = make_reader(f_in)
    header = reader.get_header()
    writer = Writer(f_out, compression=CompressionType.ZSTD)
    writer.start(profile=header.profile, library=header.library)
    schema_ids, channel_ids = {}, {}
    for schema, channel, message in reader.iter_messages(log_time_order=False):
        if channel.topic in DROPPED or channel.message_encoding != "x-mirror-repr-c":
            continue
        if schema.id not in schema_ids:
            schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channel_ids:
            channel_ids[channel.id] = writer.register_channel(
                channel.topic, channel.message_encoding, schema_ids[schema.id], channel.metadata
            )
        writer.add_message(
            channel_ids[channel.id], message.log_time, message.data, message.publish_time, message.sequence
        )
    for metadata in reader.iter_metadata():
        writer.add_metadata(metadata.name, metadata.metadata)
    for attachment in reader.iter_attachments():
        writer.add_attachment(
            attachment.log_time, attachment.create_time, attachment.name, attachment.media_type, attachment.data
        )
    writer.finish()
