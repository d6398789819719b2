#!/usr/bin/env python3
"""Independent count of a recording's losses, each once (issue 46, item 6).

Reads the recording with the PyPI `mcap` reader and `mcap-protobuf-support` (the
schemas embedded in the file) and counts, without vibrocomp's continuity code:

- per data channel, the messages *published* that the recording lacks: the seqs of the
  published log (the one `vibrocomp replay` sent, `--published`) on that topic, as a
  multiset, less the recording's;
- for `/compensated`, the outputs the recording lacks: the compensator numbers its
  outputs 0, 1, 2, ... (the test's run has no restart): the numbers between its first
  and last that are missing;
- the accelerometer blocks without an output: the `/accel` blocks, in recorded order,
  between the first and the last one that a `/compensated` block answers (`input_seq`),
  that none answers, as ranges of consecutive seqs.

A total adds each once. Prints JSON:
{"accel": {"recorded", "lost"}, "compensated": {"recorded", "lost"},
 "unanswered": {"count", "ranges": [[first, last], ...]}, "lost": total}

Usage: python3 tests/python/loss_reference.py SESSION.mcap --published FLIGHT.mcap
Requires: pip install -r tests/python/requirements.txt (exit 3 without it).
"""

import argparse
import collections
import json
import sys

try:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory
except ImportError as e:  # pragma: no cover - the message is the point
    print(
        f"loss_reference.py: missing Python package ({e}); "
        "run `pip install -r tests/python/requirements.txt`",
        file=sys.stderr,
    )
    sys.exit(3)


def messages(path, topics):
    """(topic, decoded message) of `topics`, in file order."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for _schema, channel, _message, decoded in reader.iter_decoded_messages(
            topics=topics, log_time_order=False
        ):
            yield channel.topic, decoded


def ranges(seqs):
    out = []
    for s in seqs:
        if out and out[-1][1] + 1 == s:
            out[-1][1] = s
        else:
            out.append([s, s])
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("session")
    p.add_argument("--published", required=True)
    args = p.parse_args()

    published = collections.Counter(
        m.seq for _, m in messages(args.published, ["/accel"])
    )
    accel = []
    outputs = []  # (compensator seq, input_seq)
    for topic, m in messages(args.session, ["/accel", "/compensated"]):
        if topic == "/accel":
            accel.append(m.seq)
        else:
            outputs.append((m.seq, m.input_seq))

    recorded = collections.Counter(accel)
    accel_lost = sum((published - recorded).values())

    out_seqs = sorted(s for s, _ in outputs)
    if len(set(out_seqs)) != len(out_seqs):
        sys.exit("the compensator's seq repeats: restarted (not this reference's case)")
    comp_lost = (out_seqs[-1] - out_seqs[0] + 1 - len(out_seqs)) if out_seqs else 0

    answered = set(i for _, i in outputs)
    idx = [k for k, s in enumerate(accel) if s in answered]
    unanswered = []
    if idx:
        unanswered = [s for s in accel[idx[0] : idx[-1] + 1] if s not in answered]

    print(
        json.dumps(
            {
                "accel": {"recorded": len(accel), "lost": accel_lost},
                "compensated": {"recorded": len(outputs), "lost": comp_lost},
                "unanswered": {"count": len(unanswered), "ranges": ranges(unanswered)},
                "lost": accel_lost + comp_lost + len(unanswered),
            }
        )
    )


if __name__ == "__main__":
    main()
