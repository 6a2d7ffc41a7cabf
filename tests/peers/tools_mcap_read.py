"""Independent MCAP reader for the tools test: the `mcap` Python package reads the file that
`subnav export` wrote and prints, as one JSON object, per topic: schema name, schema encoding,
message encoding, message count, and the first message's JSON keys."""
import json
import sys

from mcap.reader import make_reader

topics = {}
with open(sys.argv[1], "rb") as f:
    reader = make_reader(f)
    summary = reader.get_summary()
    for schema, channel, message in reader.iter_messages():
        t = topics.setdefault(channel.topic, {
            "schema": schema.name if schema else None,
            "schema_encoding": schema.encoding if schema else None,
            "message_encoding": channel.message_encoding,
            "count": 0,
            "keys": sorted(json.loads(message.data).keys()),
        })
        t["count"] += 1
print(json.dumps({"topics": topics, "message_count": summary.statistics.message_count if summary and summary.statistics else None}))
