#!/usr/bin/env python3
"""Independent check of a vibrocomp MCAP recording with the reference Python readers.

Decodes every message of every channel with the PyPI `mcap` reader and the
`mcap-protobuf-support` decoder (which builds the message classes from the schema
embedded in the file, as Foxglove does), with chunk CRC validation on, and prints a
JSON summary per channel: count, first/last log time and its span, the publish time's
span, sequence gaps, and the first
message's fields. Doubles appear twice: as JSON numbers in `first_message` (NaN and
infinities as strings) and as exact IEEE-754 bit patterns (unsigned 64-bit integers) in
`first_message_f64_bits`, keyed by field path, so a caller can compare bit for bit.

With --all-messages, each channel also lists every message (`messages`: sequence, log
and publish time, fields and f64 bits, as for the first message).

Usage:
    python3 tests/python/mcap_check.py FILE.mcap [--expect-counts '{"/accel": 10}'] [--all-messages]

Exits non-zero on any failure: unreadable file, CRC mismatch, a message that does not
decode, a channel without a protobuf schema, or counts different from --expect-counts.

Requires: pip install -r tests/python/requirements.txt
"""

import argparse
import json
import math
import struct
import sys

try:
    from google.protobuf.descriptor import FieldDescriptor
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory
except ImportError as e:  # pragma: no cover - the message is the point
    print(
        f"mcap_check.py: missing Python package ({e}); "
        "run `pip install -r tests/python/requirements.txt`",
        file=sys.stderr,
    )
    sys.exit(3)


def f64_bits(x):
    return struct.unpack("<Q", struct.pack("<d", x))[0]


def json_float(x):
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return x


def is_double(field):
    return field.type == FieldDescriptor.TYPE_DOUBLE


def is_message(field):
    return field.type == FieldDescriptor.TYPE_MESSAGE


def is_repeated(field):
    # `label` is deprecated in newer protobuf releases; `is_repeated` is not everywhere.
    flag = getattr(field, "is_repeated", None)
    if flag is not None:
        return flag() if callable(flag) else flag
    return field.label == FieldDescriptor.LABEL_REPEATED


def to_plain(msg, path, bits):
    """Every field of `msg` (set or not) as JSON-able values; doubles' bits into `bits`."""
    out = {}
    for field in msg.DESCRIPTOR.fields:
        value = getattr(msg, field.name)
        key = f"{path}{field.name}"
        if is_message(field):
            if is_repeated(field):
                out[field.name] = [
                    to_plain(v, f"{key}[{i}].", bits) for i, v in enumerate(value)
                ]
            else:
                out[field.name] = to_plain(value, f"{key}.", bits)
        elif is_double(field):
            if is_repeated(field):
                bits[key] = [f64_bits(v) for v in value]
                out[field.name] = [json_float(v) for v in value]
            else:
                bits[key] = f64_bits(value)
                out[field.name] = json_float(value)
        elif is_repeated(field):
            out[field.name] = list(value)
        else:
            out[field.name] = value
    return out


def check(path, all_messages=False):
    channels = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        if summary is None:
            raise RuntimeError("no summary section (was the recording finished?)")
        for channel_id, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            if schema is None or schema.encoding != "protobuf":
                raise RuntimeError(f"channel {channel.topic!r} has no protobuf schema")
            if channel.message_encoding != "protobuf":
                raise RuntimeError(
                    f"channel {channel.topic!r} has message encoding {channel.message_encoding!r}"
                )
        for schema, channel, message, decoded in reader.iter_decoded_messages(
            log_time_order=True
        ):
            c = channels.setdefault(
                channel.topic,
                {
                    "schema": schema.name,
                    "message_encoding": channel.message_encoding,
                    "count": 0,
                    "first_log_time_ns": message.log_time,
                    "last_log_time_ns": message.log_time,
                    "min_publish_time_ns": message.publish_time,
                    "max_publish_time_ns": message.publish_time,
                    "first_sequence": message.sequence,
                    "last_sequence": message.sequence,
                    "sequence_gaps": 0,
                },
            )
            if all_messages:
                bits = {}
                c.setdefault("messages", []).append(
                    {
                        "sequence": message.sequence,
                        "log_time_ns": message.log_time,
                        "publish_time_ns": message.publish_time,
                        "fields": to_plain(decoded, "", bits),
                        "f64_bits": bits,
                    }
                )
            if c["count"] == 0:
                bits = {}
                c["first_message"] = to_plain(decoded, "", bits)
                c["first_message_f64_bits"] = bits
                c["first_publish_time_ns"] = message.publish_time
            elif message.sequence != (c["last_sequence"] + 1) % 2**32:
                c["sequence_gaps"] += 1
            c["count"] += 1
            c["first_log_time_ns"] = min(c["first_log_time_ns"], message.log_time)
            c["last_log_time_ns"] = max(c["last_log_time_ns"], message.log_time)
            c["min_publish_time_ns"] = min(c["min_publish_time_ns"], message.publish_time)
            c["max_publish_time_ns"] = max(c["max_publish_time_ns"], message.publish_time)
            c["last_sequence"] = message.sequence
        for c in channels.values():
            c["span_s"] = (c["last_log_time_ns"] - c["first_log_time_ns"]) * 1e-9
            c["publish_span_s"] = (c["max_publish_time_ns"] - c["min_publish_time_ns"]) * 1e-9
        attachments = [a.name for a in reader.iter_attachments()]
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return {
        "file": path,
        "channels": channels,
        "attachments": attachments,
        "metadata": metadata,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument(
        "--expect-counts",
        help='JSON object {"topic": message count}; every topic must match exactly',
    )
    parser.add_argument(
        "--all-messages",
        action="store_true",
        help="list every message of every channel, not only the first",
    )
    args = parser.parse_args()
    try:
        result = check(args.file, args.all_messages)
    except Exception as e:  # any reader, CRC or decoder failure
        print(f"mcap_check.py: {args.file}: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    failures = []
    if args.expect_counts:
        expected = json.loads(args.expect_counts)
        seen = {t: c["count"] for t, c in result["channels"].items()}
        for topic in sorted(set(expected) | set(seen)):
            if expected.get(topic) != seen.get(topic):
                failures.append(
                    f"topic {topic!r}: expected {expected.get(topic)} messages, found {seen.get(topic)}"
                )
    result["ok"] = not failures
    result["failures"] = failures
    json.dump(result, sys.stdout, indent=1, allow_nan=False)
    print()
    for failure in failures:
        print(f"mcap_check.py: {failure}", file=sys.stderr)
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
