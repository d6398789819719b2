#!/usr/bin/env python3
"""Whether two MCAP files hold the same messages, read by the PyPI `mcap` reader.

Compares every message of A and of B (topic, schema name, sequence, log time,
publish time, bytes), as multisets (sorted), with CRC validation on, and prints
`{"a": count, "b": count, "equal": bool, "only_in_a": n, "only_in_b": n}`. Used by the
recovery tests: a recovered file against the original it was damaged from, read by a
reader that shares no code with vibrocomp.

Usage:
    python3 tests/python/mcap_same_messages.py A.mcap B.mcap

Requires: pip install -r tests/python/requirements.txt
"""

import collections
import json
import sys

try:
    from mcap.reader import make_reader
except ImportError as e:  # pragma: no cover - the message is the point
    print(
        f"mcap_same_messages.py: missing Python package ({e}); "
        "run `pip install -r tests/python/requirements.txt`",
        file=sys.stderr,
    )
    sys.exit(3)


def messages(path):
    out = collections.Counter()
    with open(path, "rb") as f:
        for schema, channel, m in make_reader(f, validate_crcs=True).iter_messages():
            name = schema.name if schema else ""
            out[(channel.topic, name, m.sequence, m.log_time, m.publish_time, bytes(m.data))] += 1
    return out


def main():
    a, b = messages(sys.argv[1]), messages(sys.argv[2])
    print(
        json.dumps(
            {
                "a": sum(a.values()),
                "b": sum(b.values()),
                "equal": a == b,
                "only_in_a": sum((a - b).values()),
                "only_in_b": sum((b - a).values()),
            }
        )
    )


if __name__ == "__main__":
    main()
