"""A Zenoh client of a vibrocomp bridge: subscribes to one bridged stream and decodes
every message by the tables of docs/messages.md alone (no vibrocomp code).

    python3 zenoh_client.py ENDPOINT KEY TYPE COUNT TIMEOUT_S

ENDPOINT is the bridge's listen endpoint (unixsock-stream//PATH/b.sock: the client runs
as the bridge's user, docs/bridge.md "Who may connect"), KEY the stream's Zenoh
key ({key_prefix}/compensated), TYPE the message type's section in docs/messages.md
(CompensatedBlock). Prints `ready` once subscribed, then one JSON line per message:
its decoded fields, doubles as their IEEE-754 bit patterns (integers) so that the
comparison is bit-exact; exits 0 after COUNT messages, 1 on a timeout or a message
whose encoding or size the document does not give.

Needs `eclipse-zenoh` of the bridge's Zenoh version (tests/python/requirements.txt).
"""

import json
import pathlib
import re
import struct
import sys
import time

import zenoh

DOC = pathlib.Path(__file__).resolve().parents[2] / "docs" / "messages.md"

# C types of docs/messages.md -> struct codes (native little-endian, docs "Byte order").
CODES = {
    "uint64_t": "Q",
    "int64_t": "q",
    "uint32_t": "I",
    "int32_t": "i",
    "uint8_t": "B",
    "double": "d",
}


def layout(type_section):
    """(type name, size, [(field, offset, size, C type)]) of `### TYPE` in the doc."""
    text = DOC.read_text()
    section = text.split(f"### {type_section}\n", 1)[1].split("\n### ", 1)[0]
    type_name = re.search(r"type name: `([^`]+)`", section).group(1)
    size = int(re.search(r"size: (\d+) bytes", section).group(1))
    fields = []
    for line in section.splitlines():
        m = re.match(r"\| `(\w+)` \| (\d+) \| (\d+) \| `([^`]+)` \|", line)
        if m:
            fields.append((m.group(1), int(m.group(2)), int(m.group(3)), m.group(4)))
    return type_name, size, fields


def decode(buf, fields):
    out = {}
    for name, offset, size, ctype in fields:
        base = ctype.split("[")[0]
        code = CODES[base]
        n = size // struct.calcsize(code)
        values = list(struct.unpack_from("<" + code * n, buf, offset))
        if base == "double":
            values = [struct.unpack("<Q", struct.pack("<d", v))[0] for v in values]
        out[name] = values if "[" in ctype else values[0]
    return out


def main():
    endpoint, key, type_section, count, timeout_s = sys.argv[1:6]
    count, timeout_s = int(count), float(timeout_s)
    type_name, size, fields = layout(type_section)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    sub = session.declare_subscriber(key)
    print("ready", flush=True)
    deadline = time.monotonic() + timeout_s
    got = 0
    status = 0
    while got < count:
        if time.monotonic() > deadline:
            print(f"timeout after {got} of {count} messages", file=sys.stderr)
            status = 1
            break
        sample = sub.try_recv()
        if sample is None:
            time.sleep(0.005)
            continue
        encoding = str(sample.encoding)
        wanted = f"application/octet-stream;{type_name}"
        payload = sample.payload.to_bytes()
        if encoding != wanted or len(payload) != size:
            print(
                f"message {got}: encoding {encoding!r}, {len(payload)} bytes; "
                f"docs/messages.md says {wanted!r}, {size} bytes",
                file=sys.stderr,
            )
            status = 1
            break
        print(json.dumps({"key": str(sample.key_expr), "fields": decode(payload, fields)}), flush=True)
        got += 1
    sub.undeclare()
    session.close()
    sys.exit(status)


if __name__ == "__main__":
    main()
