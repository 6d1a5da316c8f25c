#!/usr/bin/env python3
"""Reads gpm MCAP recordings with the independent Python `mcap` package (pip install mcap).

For each FILE: channels, schema names and encodings, message counts (against the file's own
statistics record), sequence = step and log time = simulation time in ns on /diagnostics,
and every message parses as JSON and (when the Python `jsonschema` package is present)
validates against the JSON Schema stored in the file. Point clouds and projection inputs are
decoded from base64 and their sizes checked. Then the file is cut in the middle of its data and
read again with the streaming reader, which must recover a prefix of the steps.

Usage: read_mcap.py FILE [FILE ...]      exits non-zero on the first failure.
       read_mcap.py --stream FILE MIN_STEPS  a file without footer (a killed run's
                                            run.mcap.partial): the streaming reader must read
                                            steps 1..k with k >= MIN_STEPS.
"""

import base64
import io
import json
import sys

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.records import Message, Channel, Schema

try:
    import jsonschema  # optional
except ImportError:  # pragma: no cover
    jsonschema = None

EXPECTED = {
    "/config": "gpm.RunConfig",
    "/diagnostics": "gpm.StepDiagnostics",
    "/particles": "foxglove.PointCloud",
    "/projection_input": "gpm.ProjectionInput",
}
DTYPE_SIZE = {"<f8": 8, "<u4": 4, "|u1": 1}


def fail(msg):
    print(f"FAIL: {msg}")
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)


def check_file(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        check(summary is not None, f"{path}: no summary (file not finished?)")
        topics = {}
        for cid, ch in summary.channels.items():
            schema = summary.schemas[ch.schema_id]
            check(ch.topic in EXPECTED, f"{path}: unexpected channel {ch.topic}")
            check(schema.name == EXPECTED[ch.topic],
                  f"{path}: {ch.topic} has schema {schema.name}, expected {EXPECTED[ch.topic]}")
            check(schema.encoding == "jsonschema", f"{path}: schema encoding {schema.encoding}")
            check(ch.message_encoding == "json", f"{path}: message encoding {ch.message_encoding}")
            topics[cid] = ch.topic
        check("/config" in topics.values() and "/diagnostics" in topics.values(),
              f"{path}: missing /config or /diagnostics: {sorted(topics.values())}")

        validators = {}
        counts = {t: 0 for t in topics.values()}
        steps = []
        level = None
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            doc = json.loads(message.data)
            if jsonschema is not None:
                if schema.id not in validators:
                    s = json.loads(schema.data)
                    jsonschema.Draft202012Validator.check_schema(s)
                    validators[schema.id] = jsonschema.Draft202012Validator(s)
                errors = list(validators[schema.id].iter_errors(doc))
                check(not errors, f"{path}: {channel.topic} {message.sequence}: {errors[:1]}")
            if channel.topic == "/config":
                check(doc["format"] == "gpm-mcap", f"{path}: format {doc['format']}")
                level = doc["level"]
            elif channel.topic == "/diagnostics":
                check(message.sequence == doc["step"], f"{path}: sequence != step")
                check(message.log_time == round(doc["time"] * 1e9),
                      f"{path}: log time {message.log_time} != time {doc['time']} s")
                steps.append(doc["step"])
            elif channel.topic == "/particles":
                raw = base64.b64decode(doc["data"])
                check(len(raw) % doc["point_stride"] == 0, f"{path}: ragged point cloud")
                names = [fl["name"] for fl in doc["fields"]]
                check(names[:3] == ["x", "y", "z"], f"{path}: point fields {names}")
            elif channel.topic == "/projection_input":
                n = doc["particles"]
                for key in ("x", "vol", "u_star", "p_in", "u_out", "p_out", "phi", "role_kind"):
                    a = doc[key]
                    size = 1
                    for s in a["shape"]:
                        size *= s
                    check(a["shape"][0] == n, f"{path}: {key} shape {a['shape']} for {n} particles")
                    check(len(base64.b64decode(a["data"])) == size * DTYPE_SIZE[a["dtype"]],
                          f"{path}: {key} byte count")

        stats = summary.statistics
        for cid, topic in topics.items():
            announced = stats.channel_message_counts.get(cid, 0)
            check(counts[topic] == announced,
                  f"{path}: {topic}: read {counts[topic]} messages, statistics say {announced}")
        check(counts["/config"] == 1, f"{path}: {counts['/config']} /config messages")
        check(steps == list(range(1, len(steps) + 1)), f"{path}: steps are not 1..N")
        if level == "full":
            check(counts.get("/particles", 0) > 0, f"{path}: level full without /particles")

    # a file cut in the middle: the streaming reader recovers a prefix of the steps
    data = open(path, "rb").read()
    cut = data[: len(data) // 2]
    recovered = []
    channels = {}
    try:
        for record in StreamReader(io.BytesIO(cut), skip_magic=False).records:
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message) and channels.get(record.channel_id) == "/diagnostics":
                recovered.append(json.loads(record.data)["step"])
    except Exception as e:  # the reader stops at the cut
        print(f"  cut copy: streaming reader stopped with {type(e).__name__}")
    check(recovered == steps[: len(recovered)], f"{path}: recovered steps are not a prefix")

    desc = ", ".join(f"{t} {c}" for t, c in sorted(counts.items()))
    print(f"ok {path}: {desc}; {len(recovered)} of {len(steps)} steps recovered from the half file"
          + ("" if jsonschema else " (jsonschema not installed: schemas not checked)"))


def check_stream(path, min_steps):
    steps = []
    channels = {}
    try:
        for record in StreamReader(open(path, "rb"), skip_magic=False).records:
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message) and channels.get(record.channel_id) == "/diagnostics":
                steps.append(json.loads(record.data)["step"])
    except Exception as e:  # the reader stops where the file ends
        print(f"  streaming reader stopped with {type(e).__name__}")
    check(steps == list(range(1, len(steps) + 1)), f"{path}: steps are not 1..N")
    check(len(steps) >= min_steps, f"{path}: {len(steps)} steps, expected at least {min_steps}")
    print(f"ok {path}: streaming reader read steps 1..{len(steps)}")


def main():
    if len(sys.argv) == 4 and sys.argv[1] == "--stream":
        check_stream(sys.argv[2], int(sys.argv[3]))
        return
    if len(sys.argv) < 2:
        print(__doc__)
        sys.exit(2)
    for p in sys.argv[1:]:
        check_file(p)
    print(f"{len(sys.argv) - 1} passed, 0 failed")


if __name__ == "__main__":
    main()
