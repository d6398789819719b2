#!/usr/bin/env python3
"""How fast `vibrocomp.Log(path).stream(topic)` reads one stream of an MCAP log,
against the PyPI `mcap` reader on the same file.

Two readers, each timed over the same file and topic:

  mcap       `make_reader(f).iter_messages(topics=[topic])`, counting the messages
             and nothing else: the chunks holding the topic are read and
             decompressed, each message record is parsed, no payload is decoded.
  vibrocomp  `vibrocomp.Log(path).stream(topic)`: opens the log (reads and checks
             its summary), reads the same chunks, decodes every protobuf message of
             the channel and builds the numpy arrays (one row per block in `rows`,
             one per sample in `samples`; `/accel` gives `samples["output_v"]` of
             shape (N, 3)).

Why the mcap reader is the reference: it is the independent Python implementation of
the format (the one `mcap_check.py` checks the logs with), and it decompresses the
same chunks; what it does is the floor of what any Python-facing reader of the stream
must do. vibrocomp does strictly more (protobuf decoding, array building), so the
requirement is stated as a ratio: vibrocomp <= 2x the mcap reader.

Each reader runs once untimed (to warm the page cache and the imports), then R times
(`--repeat`, default 5); the report gives the median and the minimum wall time
(`time.perf_counter`, the file opened inside the timed region for both), the messages
and samples read, and the ratio vibrocomp / mcap of the medians and of the minima.
The readers must agree: the mcap reader's message count must equal `len(stream)`
(the stream's rows, one per block); otherwise the script exits with status 1.
The garbage collector is left as it is.

Usage:
    python3 tests/python/bench_log_read.py --log FILE.mcap [--topic /accel] [--repeat 5] [--json]

Requires: pip install -r tests/python/requirements.txt, and the `vibrocomp` package.
"""

import argparse
import json
import os
import statistics
import sys
import time

try:
    from mcap.reader import make_reader

    import vibrocomp
except ImportError as e:  # pragma: no cover - the message is the point
    print(
        f"bench_log_read.py: missing Python package ({e}); "
        "run `pip install -r tests/python/requirements.txt` and install vibrocomp",
        file=sys.stderr,
    )
    sys.exit(3)


def read_mcap(path, topic):
    """The messages on `topic`, counted with the PyPI mcap reader (no decoding)."""
    n = 0
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, _channel, _message in reader.iter_messages(topics=[topic]):
            n += 1
    return {"messages": n, "samples": None}


def read_vibrocomp(path, topic):
    """The stream on `topic`, read into numpy arrays by vibrocomp."""
    stream = vibrocomp.Log(path).stream(topic)
    samples = None
    if stream.samples:
        samples = len(next(iter(stream.samples.values())))
    return {"messages": len(stream), "samples": samples}


READERS = (("mcap", read_mcap), ("vibrocomp", read_vibrocomp))


def measure(fn, path, topic, repeat):
    fn(path, topic)  # warm-up: page cache, imports, allocator
    times = []
    result = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn(path, topic)
        times.append(time.perf_counter() - t0)
    return {
        "median_s": statistics.median(times),
        "min_s": min(times),
        "times_s": times,
        "messages": result["messages"],
        "samples": result["samples"],
    }


def main(argv=None):
    parser = argparse.ArgumentParser(
        description="Times vibrocomp.Log(path).stream(topic) against the PyPI mcap reader."
    )
    parser.add_argument("--log", required=True, help="the MCAP log")
    parser.add_argument("--topic", default="/accel", help="the stream (default /accel)")
    parser.add_argument(
        "--repeat", type=int, default=5, help="timed runs per reader (default 5)"
    )
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat must be at least 1")
    if not os.path.isfile(args.log):
        parser.error(f"no such file: {args.log}")

    results = {name: measure(fn, args.log, args.topic, args.repeat) for name, fn in READERS}
    m, v = results["mcap"], results["vibrocomp"]
    ratio_median = v["median_s"] / m["median_s"] if m["median_s"] > 0 else float("inf")
    ratio_min = v["min_s"] / m["min_s"] if m["min_s"] > 0 else float("inf")
    agree = m["messages"] == v["messages"]
    report = {
        "log": args.log,
        "file_bytes": os.path.getsize(args.log),
        "topic": args.topic,
        "repeat": args.repeat,
        "readers": results,
        "ratio_median": ratio_median,
        "ratio_min": ratio_min,
        "limit_ratio": 2.0,
        "within_limit": ratio_median <= 2.0,
        "counts_agree": agree,
    }

    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(
            f"{args.log} ({report['file_bytes'] / 1e6:.1f} MB), topic {args.topic}, "
            f"{args.repeat} runs per reader after one warm-up"
        )
        print(f"{'reader':<10} {'median s':>10} {'min s':>10} {'messages':>10} {'samples':>10}")
        for name, r in results.items():
            samples = "-" if r["samples"] is None else str(r["samples"])
            print(
                f"{name:<10} {r['median_s']:>10.3f} {r['min_s']:>10.3f} "
                f"{r['messages']:>10} {samples:>10}"
            )
        verdict = "within" if report["within_limit"] else "OVER"
        print(
            f"vibrocomp / mcap: {ratio_median:.2f}x (medians), {ratio_min:.2f}x (minima); "
            f"{verdict} the 2x limit"
        )
        print(
            "message counts agree"
            if agree
            else f"MISMATCH: mcap read {m['messages']} messages, vibrocomp {v['messages']} rows"
        )
    return 0 if agree else 1


if __name__ == "__main__":
    sys.exit(main())
