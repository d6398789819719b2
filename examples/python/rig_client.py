#!/usr/bin/env python3
"""A rig client of vibrocomp in Python, over iceoryx2 shared memory.

Plays the rig bridge: publishes a deterministic synthetic rig stream on
``{prefix}vib`` (vibration sensors, ``VibBlock``) and ``{prefix}accel`` (accelerometer
triad, ``AccelBlock``) with its reference beside the readings on ``{prefix}truth``
(``TruthBlock`` flagged ``SENSED_UNKNOWN``: what each unit should read without
vibration, as ``vibrocomp log import --rig`` writes a rig's reference, so that a
recording of the session can be measured with ``vibrocomp log errors``), reads back
every ``CompensatedBlock`` from ``{prefix}compensated``, and writes them to a JSON
file. Run the two services first
(``vibrocomp service estimator --prefix P`` and ``vibrocomp service compensator
--prefix P``), then ``python3 rig_client.py --prefix P --out results.json``.

The stream, in data time (no real-time pacing; the same bytes on every run):

- vibration sensors, 25.6 kHz, sample ``k`` at ``t_k = k / 25600`` s, axis ``a``:
  ``0.1 V/g * TONE_G[a] * sin(2 pi TONE_HZ t_k + TONE_RAD[a])``, blocks of 512;
- accelerometers, 800 Hz, sample ``n`` the mean over ``(n T, (n + 1) T]``, unit ``u``:
  ``U = (1.0 + 1e-4 * ((n * (u + 1)) % 1000)) * K1`` volts (about 1 g along each IA,
  ramping by up to 0.1 g), ``K1 = K1_v_per_g`` of the AL-15 passport; blocks of 32.

Flow control, so that no buffer (256 deep, safe overflow off) ever fills and the
outputs do not depend on timing: before each accelerometer block the client sends the
vibration blocks up to that block's end and waits until the estimator's progress
stream (``{prefix}progress/estimator``) says it consumed them, which means every
estimate they completed is already published; at most ``--max-in-flight``
accelerometer blocks wait for their compensated block, and none when the next
vibration blocks complete an estimate (the progress stream's
``input_samples_to_output``): a compensator that is behind would otherwise take that
newer estimate for a block sent before it.

Wire layouts, type names and QoS: ``docs/messages.md`` and ``shared/vibro-ipc``. They
must match the Rust side exactly or iceoryx2 refuses to open the services.
"""

from __future__ import annotations

import argparse
import ctypes as C
import json
import math
import re
import struct
import sys
import time
from importlib import metadata
from pathlib import Path

ICEORYX2_VERSION = "0.10.0"
PIP_HINT = "pip install -r examples/python/requirements.txt"

try:
    import iceoryx2 as iox2
except ImportError as e:  # pragma: no cover - depends on the environment
    sys.exit(f"rig_client: cannot import iceoryx2 ({e}): {PIP_HINT}")

# --- The message contracts (docs/messages.md) -----------------------------------------

#: Every type name ends in ``::v{SCHEMA_VERSION}`` (``vibro_msgs::SCHEMA_VERSION``).
SCHEMA_VERSION = 5
UNITS = 3
ACCEL_BLOCK_MAX = 32
VIB_BLOCK_MAX = 512
MAX_TONES = 16
MAX_BANDS = 16

F64 = C.c_double
U64 = C.c_uint64
U32 = C.c_uint32
U8 = C.c_uint8


def wire(size: int):
    """Gives a ctypes struct its iceoryx2 type name and checks its size and alignment."""

    def mark(cls):
        name = f"vibrocomp::{cls.__name__}::v{SCHEMA_VERSION}"
        # iceoryx2's Python binding takes the payload's type name from `type_name()`.
        cls.type_name = staticmethod(lambda: name)
        assert C.sizeof(cls) == size, f"{cls.__name__}: {C.sizeof(cls)} bytes, want {size}"
        assert C.alignment(cls) == 8, f"{cls.__name__}: alignment {C.alignment(cls)}"
        return cls

    return mark


@wire(824)
class AccelBlock(C.Structure):
    _fields_ = [
        ("seq", U64),
        ("first_sample_index", U64),
        ("t0_ns", U64),
        ("sample_period_ns", U64),
        ("publish_ns", U64),
        ("output_v", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("count", U32),
        ("source_id", U32),
        ("flags", U32),
        ("_pad", U8 * 4),
    ]


@wire(2360)
class TruthBlock(C.Structure):
    """The reference channel (`{prefix}truth`): a rig states what each unit should
    read without vibration (`a_l_ia_g`), flagged SENSED_UNKNOWN, the other two NaN."""

    _fields_ = [
        ("seq", U64),
        ("first_sample_index", U64),
        ("t0_ns", U64),
        ("sample_period_ns", U64),
        ("publish_ns", U64),
        ("a_l_ia_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("a_sensed_ia_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("vib_error_ia_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("count", U32),
        ("source_id", U32),
        ("flags", U32),
        ("_pad", U8 * 4),
    ]


#: `truth_flags::SENSED_UNKNOWN` (docs/messages.md): a rig's reference.
TRUTH_SENSED_UNKNOWN = 1 << 2


@wire(12344)
class VibBlock(C.Structure):
    _fields_ = [
        ("seq", U64),
        ("first_sample_index", U64),
        ("t0_ns", U64),
        ("sample_period_ns", U64),
        ("publish_ns", U64),
        ("sample_v", (F64 * UNITS) * VIB_BLOCK_MAX),
        ("count", U32),
        ("source_id", U32),
        ("flags", U32),
        ("_pad", U8 * 4),
    ]


@wire(3936)
class VibEstimate(C.Structure):
    _fields_ = [
        ("seq", U64),
        ("index", U64),
        ("source_seq", U64),
        ("publish_ns", U64),
        ("start_ns", U64),
        ("end_ns", U64),
        ("center_ns", U64),
        ("broadband_f_lo_hz", F64),
        ("broadband_f_hi_hz", F64),
        ("broadband_rms_g", F64 * UNITS),
        ("broadband_rms_u_g", F64 * UNITS),
        ("broadband_covariance_g2", (F64 * UNITS) * UNITS),
        ("broadband_covariance_u_g2", (F64 * UNITS) * UNITS),
        ("broadband_kurtosis", F64 * UNITS),
        ("broadband_kurtosis_u", F64 * UNITS),
        ("tone_frequency_hz", F64 * MAX_TONES),
        ("tone_frequency_u_hz", F64 * MAX_TONES),
        ("tone_amplitude_g", (F64 * UNITS) * MAX_TONES),
        ("tone_amplitude_u_g", (F64 * UNITS) * MAX_TONES),
        ("tone_phase_rad", (F64 * UNITS) * MAX_TONES),
        ("tone_phase_u_rad", (F64 * UNITS) * MAX_TONES),
        ("tone_snr_db", (F64 * UNITS) * MAX_TONES),
        ("band_f_lo_hz", F64 * MAX_BANDS),
        ("band_f_hi_hz", F64 * MAX_BANDS),
        ("band_psd_g2_per_hz", (F64 * UNITS) * MAX_BANDS),
        ("band_psd_u_g2_per_hz", (F64 * UNITS) * MAX_BANDS),
        ("band_rms_g", (F64 * UNITS) * MAX_BANDS),
        ("samples", U32),
        ("valid_samples", U32),
        ("saturated_samples", U32 * UNITS),
        ("broadband_welch_segments", U32),
        ("tone_count", U32),
        ("band_count", U32),
        ("flags", U32),
        ("welch_segment_samples", U32),
    ]


@wire(5472)
class CompensatedBlock(C.Structure):
    _fields_ = [
        ("seq", U64),
        ("input_seq", U64),
        ("first_sample_index", U64),
        ("t0_ns", U64),
        ("sample_period_ns", U64),
        ("estimate_seq", U64),
        ("input_publish_ns", U64),
        ("recv_ns", U64),
        ("publish_ns", U64),
        ("estimate_age_ns", C.c_int64),
        ("a1_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("a2_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("a3_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("a4_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("main_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("det_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("rand_g", (F64 * UNITS) * ACCEL_BLOCK_MAX),
        ("count", U32),
        ("source_id", U32),
        ("flags", U32),
        ("mode", U8),
        ("_pad", U8 * 3),
    ]


@wire(112)
class Heartbeat(C.Structure):
    _fields_ = [
        ("seq", U64),
        ("publish_ns", U64),
        ("uptime_ns", U64),
        ("received", U64),
        ("published", U64),
        ("lost", U64),
        ("stale", U64),
        ("latency_p50_ns", U64),
        ("latency_p99_ns", U64),
        ("input_samples_to_output", U64),
        ("input_samples_per_output", U64),
        ("out_of_order", U64),
        ("resyncs", U64),
        ("service", U8),
        ("state", U8),
        ("_pad", U8 * 6),
    ]


WIRE_TYPES = (AccelBlock, VibBlock, VibEstimate, CompensatedBlock, Heartbeat, TruthBlock)

# --- Quality of service (shared/vibro-ipc StreamConfig::default) ------------------------

SUBSCRIBER_BUFFER = 256
MAX_PUBLISHERS = 2
MAX_SUBSCRIBERS = 8
MAX_NODES = 16
#: History of `{prefix}estimate` (the latest estimate for a late subscriber); 0 elsewhere.
ESTIMATE_HISTORY = 1

# --- The synthetic rig ------------------------------------------------------------------

VIB_RATE_HZ = 25600
ACCEL_RATE_HZ = 800
SENSITIVITY_V_PER_G = 0.1
TONE_HZ = 12.0
TONE_G = (1.2, 0.8, 0.5)
TONE_RAD = (0.3, -1.1, 2.0)
SOURCE_ID = 42


def period_ns(rate_hz: int) -> int:
    """`round(1e9 / rate)`, half away from zero, as the Rust Packetizer rounds."""
    return (2 * 10**9 + rate_hz) // (2 * rate_hz)


def time_ns(index: int, rate_hz: int) -> int:
    """`round(index * 1e9 / rate)` in exact integer arithmetic (index >= 0)."""
    return (2 * index * 10**9 + rate_hz) // (2 * rate_hz)


def accel_g(n: int, u: int) -> float:
    """Acceleration along unit `u`'s IA over output interval `n`, g. The Rust test
    (tests/integration/python_client.rs) repeats this formula operation for operation."""
    return 1.0 + 1e-4 * ((n * (u + 1)) % 1000)


def read_k1_v_per_g(passport: Path) -> float:
    text = passport.read_text(encoding="utf-8")
    m = re.search(r"^\s*K1_v_per_g\s*=\s*([-+0-9.eE_]+)", text, re.MULTILINE)
    if m is None:
        raise SystemExit(f"rig_client: {passport}: no K1_v_per_g key")
    return float(m.group(1).replace("_", ""))


# --- Transport --------------------------------------------------------------------------


class RigError(Exception):
    """A failure the client reports and exits 1 with."""


def service_name(name: str):
    return iox2.ServiceName.new(name)


def open_stream(node, name: str, payload, history: int = 0):
    """Opens (or creates) a publish-subscribe service with vibro-ipc's QoS."""
    try:
        return (
            node.service_builder(service_name(name))
            .publish_subscribe(payload)
            .enable_safe_overflow(False)
            .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
            .history_size(history)
            .max_publishers(MAX_PUBLISHERS)
            .max_subscribers(MAX_SUBSCRIBERS)
            .max_nodes(MAX_NODES)
            .open_or_create()
        )
    except Exception as e:
        raise RigError(
            f"opening {name!r} ({payload.type_name()}, {C.sizeof(payload)} bytes): {e!r}; "
            "a type name, size or QoS that differs from the Rust side is refused"
        ) from e


def open_event(node, name: str):
    """Opens (or creates) the event service beside a stream, as vibro-ipc does."""
    try:
        return (
            node.service_builder(service_name(name))
            .event()
            .max_nodes(MAX_NODES)
            .max_notifiers(MAX_PUBLISHERS + 2)
            .max_listeners(MAX_SUBSCRIBERS + 2)
            .open_or_create()
        )
    except Exception as e:
        raise RigError(f"opening event service {name!r}: {e!r}") from e


class Outbound:
    """A publisher plus the notifier of its `/event` service, notified after each send."""

    def __init__(self, node, name: str, payload):
        self.name = name
        self.service = open_stream(node, name, payload)
        # No waiting inside iceoryx2: the flow control below keeps every buffer from
        # filling, and a delivery that still fails is reported, never retried blindly.
        self.publisher = (
            self.service.publisher_builder()
            .backpressure_strategy(iox2.BackpressureStrategy.DiscardData)
            .create()
        )
        self.notifier = open_event(node, name + "/event").notifier_builder().create()
        self.sent = 0

    def subscribers(self) -> int:
        return self.service.dynamic_config.number_of_subscribers

    def send(self, msg) -> None:
        expected = self.subscribers()
        sample = self.publisher.loan_uninit().write_payload(msg)
        reached = sample.send()
        self.sent += 1
        self.notifier.notify()
        if reached < expected:
            raise RigError(
                f"{self.name}: message seq {msg.seq} reached {reached} of {expected} "
                "subscribers (a buffer was full: the consumer fell behind)"
            )

    def close(self) -> None:
        self.notifier.delete()
        self.publisher.delete()


class Inbound:
    """A subscriber plus a listener on its `/event` service."""

    def __init__(self, node, name: str, payload, history: int = 0):
        self.name = name
        self.payload = payload
        self.service = open_stream(node, name, payload, history)
        self.subscriber = (
            self.service.subscriber_builder().buffer_size(SUBSCRIBER_BUFFER).create()
        )
        self.listener = open_event(node, name + "/event").listener_builder().create()

    def drain(self):
        """Copies out every pending message (releasing the shared-memory samples)."""
        out = []
        while True:
            sample = self.subscriber.receive()
            if sample is None:
                return out
            msg = self.payload()
            C.memmove(C.addressof(msg), sample.payload_ptr, C.sizeof(msg))
            sample.delete()
            out.append(msg)

    def sleep(self, timeout_s: float) -> None:
        """Sleeps until the publisher notifies, or `timeout_s`."""
        self.listener.timed_wait(iox2.Duration.from_secs_f64(max(timeout_s, 1e-4)))

    def close(self) -> None:
        self.listener.delete()
        self.subscriber.delete()


# --- The client -------------------------------------------------------------------------


def finite(x: float):
    return x if math.isfinite(x) else None


def rows(msg, field: str, count: int, fmt: str):
    """The first `count` rows of a `double[N][3]` field, as floats (`d`) or as their
    IEEE-754 bit patterns (`Q`, exact through any JSON parser)."""
    values = struct.unpack_from(f"={3 * count}{fmt}", msg, getattr(type(msg), field).offset)
    if fmt == "d":
        values = [finite(v) for v in values]
    return [list(values[3 * k : 3 * k + 3]) for k in range(count)]


class Client:
    def __init__(self, args):
        self.args = args
        self.timeout_s = args.timeout_s
        self.k1_v_per_g = read_k1_v_per_g(args.passport)
        # IOX2_LOG_LEVEL overrides; iceoryx2's warning about running without a config
        # file is noise here.
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        self.node = (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new("vibrocomp-python-rig"))
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )
        p = args.prefix
        self.vib = Outbound(self.node, p + "vib", VibBlock)
        self.accel = Outbound(self.node, p + "accel", AccelBlock)
        # The rig's reference beside the readings (what the lab and `log errors` measure
        # against); nobody needs to subscribe.
        self.truth = Outbound(self.node, p + "truth", TruthBlock)
        self.compensated = Inbound(self.node, p + "compensated", CompensatedBlock)
        self.estimate = Inbound(self.node, p + "estimate", VibEstimate, ESTIMATE_HISTORY)
        self.progress = Inbound(self.node, p + "progress/estimator", Heartbeat)
        self.vib_block = VibBlock(source_id=SOURCE_ID, sample_period_ns=period_ns(VIB_RATE_HZ))
        self.accel_block = AccelBlock(
            source_id=SOURCE_ID, sample_period_ns=period_ns(ACCEL_RATE_HZ)
        )
        self.truth_block = TruthBlock(
            source_id=SOURCE_ID,
            sample_period_ns=period_ns(ACCEL_RATE_HZ),
            flags=TRUTH_SENSED_UNKNOWN,
        )
        self.vib_total = round(args.duration_s * VIB_RATE_HZ)
        self.accel_total = round(args.duration_s * ACCEL_RATE_HZ)
        self.vib_next = 0
        self.accel_next = 0
        self.estimator_received = 0
        # Vibration samples the estimator still needs for its next estimate (its
        # progress stream's `input_samples_to_output`), None until it reported.
        self.samples_to_estimate: int | None = None
        self.estimates = []
        self.expected_estimate = {}
        self.blocks = []

    def close(self) -> None:
        for port in (
            self.progress,
            self.estimate,
            self.compensated,
            self.truth,
            self.accel,
            self.vib,
        ):
            port.close()

    def wait_for(self, what, done, inbound: Inbound | None) -> None:
        """Polls `done` (sleeping on `inbound`'s listener) until it holds; after
        `--timeout-s` fails with the message `what()` gives then."""
        deadline = time.monotonic() + self.timeout_s
        while not done():
            left = deadline - time.monotonic()
            if left <= 0:
                raise RigError(f"{what()}: not within {self.timeout_s} s")
            if inbound is None:
                time.sleep(min(left, 0.01))
            else:
                inbound.sleep(min(left, 0.1))

    # Vibration sensors.

    def send_vib_block(self) -> None:
        b = self.vib_block
        k0 = self.vib_next
        n = min(VIB_BLOCK_MAX, self.vib_total - k0)
        w = 2.0 * math.pi * TONE_HZ / VIB_RATE_HZ
        amp_v = [SENSITIVITY_V_PER_G * a for a in TONE_G]
        flat = [0.0] * (3 * VIB_BLOCK_MAX)
        for k in range(n):
            x = w * (k0 + k)
            for a in range(UNITS):
                flat[3 * k + a] = amp_v[a] * math.sin(x + TONE_RAD[a])
        struct.pack_into(f"={3 * VIB_BLOCK_MAX}d", b, VibBlock.sample_v.offset, *flat)
        b.seq = self.vib.sent
        b.first_sample_index = k0
        b.t0_ns = time_ns(k0, VIB_RATE_HZ)
        b.count = n
        b.publish_ns = time.monotonic_ns()
        self.vib.send(b)
        self.vib_next += n

    def take_progress(self) -> bool:
        for hb in self.progress.drain():
            if hb.received >= self.estimator_received:
                self.samples_to_estimate = hb.input_samples_to_output
            self.estimator_received = max(self.estimator_received, hb.received)
        for e in self.estimate.drain():
            self.estimates.append(self.estimate_record(e))
        return self.estimator_received >= self.vib.sent

    def sync_estimator(self) -> None:
        """Waits until the estimator consumed every vibration block sent: every estimate
        they completed is then published (and taken here)."""
        self.wait_for(
            lambda: f"the estimator consuming every block of {self.args.prefix}vib "
            f"(it reported {self.estimator_received} of {self.vib.sent} on "
            f"{self.args.prefix}progress/estimator)",
            self.take_progress,
            self.progress,
        )
        # The estimates were published before the progress message: take them all.
        self.take_progress()

    @staticmethod
    def estimate_record(e: VibEstimate) -> dict:
        n = min(e.tone_count, MAX_TONES)
        return {
            "seq": e.seq,
            "source_seq": e.source_seq,
            "start_ns": e.start_ns,
            "end_ns": e.end_ns,
            "flags": e.flags,
            "valid_samples": e.valid_samples,
            "tone_count": e.tone_count,
            "tone_frequency_hz": [finite(e.tone_frequency_hz[k]) for k in range(n)],
            "tone_amplitude_g": [[finite(v) for v in e.tone_amplitude_g[k]] for k in range(n)],
            "broadband_rms_g": [finite(v) for v in e.broadband_rms_g],
        }

    # Accelerometers.

    def send_accel_block(self) -> None:
        b = self.accel_block
        n0 = self.accel_next
        n = min(ACCEL_BLOCK_MAX, self.accel_total - n0)
        flat = [0.0] * (3 * ACCEL_BLOCK_MAX)
        for k in range(n):
            for u in range(UNITS):
                flat[3 * k + u] = accel_g(n0 + k, u) * self.k1_v_per_g
        struct.pack_into(f"={3 * ACCEL_BLOCK_MAX}d", b, AccelBlock.output_v.offset, *flat)
        b.seq = self.accel.sent
        b.first_sample_index = n0
        # `t0_ns` is the END of sample 0's averaging interval (docs/messages.md).
        b.t0_ns = time_ns(n0 + 1, ACCEL_RATE_HZ)
        b.count = n
        self.expected_estimate[b.seq] = self.estimates[-1]["seq"] if self.estimates else None
        b.publish_ns = time.monotonic_ns()
        self.accel.send(b)
        self.send_reference(b)
        self.accel_next += n

    def send_reference(self, accel: AccelBlock) -> None:
        """The block's reference: the acceleration each unit's IA sees (`accel_g`),
        which this rig knows; the sensed acceleration and VE are not known (NaN)."""
        t = self.truth_block
        n0, n = accel.first_sample_index, accel.count
        known = [0.0] * (3 * ACCEL_BLOCK_MAX)
        for k in range(n):
            for u in range(UNITS):
                known[3 * k + u] = accel_g(n0 + k, u)
        unknown = [math.nan] * (3 * ACCEL_BLOCK_MAX)
        struct.pack_into(f"={3 * ACCEL_BLOCK_MAX}d", t, TruthBlock.a_l_ia_g.offset, *known)
        for field in (TruthBlock.a_sensed_ia_g, TruthBlock.vib_error_ia_g):
            struct.pack_into(f"={3 * ACCEL_BLOCK_MAX}d", t, field.offset, *unknown)
        t.seq = accel.seq
        t.first_sample_index = n0
        t.t0_ns = accel.t0_ns
        t.count = n
        t.publish_ns = accel.publish_ns
        self.truth.send(t)

    def take_compensated(self) -> None:
        for m in self.compensated.drain():
            count = min(m.count, ACCEL_BLOCK_MAX)
            self.blocks.append(
                {
                    "seq": m.seq,
                    "input_seq": m.input_seq,
                    "first_sample_index": m.first_sample_index,
                    "t0_ns": m.t0_ns,
                    "count": m.count,
                    "flags": m.flags,
                    "mode": m.mode,
                    "estimate_seq": m.estimate_seq,
                    "estimate_age_ns": m.estimate_age_ns,
                    "expected_estimate_seq": self.expected_estimate.get(m.input_seq),
                    # The compensator's receive -> publish time for this block.
                    "service_latency_ns": m.publish_ns - m.recv_ns,
                    **{f: rows(m, f, count, "d") for f in ("a1_g", "a2_g", "a3_g", "a4_g")},
                    "bits": {f: rows(m, f, count, "Q") for f in ("a1_g", "a2_g", "a3_g", "a4_g")},
                }
            )

    def wait_compensated(self, outstanding: int) -> None:
        """Waits until at most `outstanding` accelerometer blocks lack their output."""

        def done() -> bool:
            self.take_compensated()
            return self.accel.sent - len(self.blocks) <= outstanding

        self.wait_for(
            lambda: f"the CompensatedBlock of accel seq {len(self.blocks)} on "
            f"{self.args.prefix}compensated ({len(self.blocks)} of {self.accel.sent} back)",
            done,
            self.compensated,
        )

    def wait_for_services(self) -> None:
        for out, who in ((self.vib, "estimator"), (self.accel, "compensator")):
            self.wait_for(
                lambda: f"a subscriber on {out.name} (is the {who} running with "
                f"--prefix {self.args.prefix}?)",
                lambda: out.subscribers() > 0,
                None,
            )

    def before_an_estimate(self, end_ns: int) -> None:
        """If the vibration blocks up to `end_ns` will complete an estimate, waits until
        no accelerometer block is still waiting for its output: a compensator that is
        behind would otherwise take the new estimate for a block sent before it, and
        the outputs would depend on timing."""
        k, new = self.vib_next, 0
        while k < self.vib_total and time_ns(k, VIB_RATE_HZ) < end_ns:
            step = min(VIB_BLOCK_MAX, self.vib_total - k)
            new += step
            k += step
        if new and (self.samples_to_estimate is None or new >= self.samples_to_estimate):
            self.wait_compensated(0)

    def run(self) -> dict:
        start = time.monotonic()
        self.wait_for_services()
        period = period_ns(ACCEL_RATE_HZ)
        while self.accel_next < self.accel_total:
            count = min(ACCEL_BLOCK_MAX, self.accel_total - self.accel_next)
            # End of the block's last averaging interval.
            end_ns = time_ns(self.accel_next + 1, ACCEL_RATE_HZ) + (count - 1) * period
            sent_vib = self.vib.sent
            self.before_an_estimate(end_ns)
            while self.vib_next < self.vib_total and time_ns(self.vib_next, VIB_RATE_HZ) < end_ns:
                self.send_vib_block()
            if self.vib.sent != sent_vib:
                self.sync_estimator()
            self.send_accel_block()
            if self.accel.sent - len(self.blocks) >= self.args.max_in_flight:
                self.wait_compensated(self.args.max_in_flight - 1)
        self.wait_compensated(0)
        while self.vib_next < self.vib_total:
            self.send_vib_block()
        self.sync_estimator()
        self.wait_compensated(0)
        wall_s = time.monotonic() - start
        inputs = [b["input_seq"] for b in self.blocks]
        if inputs != list(range(self.accel.sent)):
            raise RigError(
                f"compensated blocks came back for input seqs {inputs[:8]}...; "
                f"want 0..{self.accel.sent - 1} once each, in order"
            )
        return {
            "client": "examples/python/rig_client.py",
            "iceoryx2": metadata.version("iceoryx2"),
            "prefix": self.args.prefix,
            "duration_s": self.args.duration_s,
            "k1_v_per_g": self.k1_v_per_g,
            "source_id": SOURCE_ID,
            "type_names": {t.__name__: t.type_name() for t in WIRE_TYPES},
            "sent": {
                "vib_blocks": self.vib.sent,
                "vib_samples": self.vib_next,
                "accel_blocks": self.accel.sent,
                "accel_samples": self.accel_next,
                "reference_blocks": self.truth.sent,
            },
            "estimator_received": self.estimator_received,
            "received_blocks": len(self.blocks),
            "wall_s": wall_s,
            "estimates": self.estimates,
            "blocks": self.blocks,
        }


def layout() -> dict:
    """Every wire type's name, size, alignment and fields (checked by the Rust test)."""
    return {
        t.__name__: {
            "type_name": t.type_name(),
            "size": C.sizeof(t),
            "alignment": C.alignment(t),
            "fields": [
                [name, getattr(t, name).offset, getattr(t, name).size] for name, _ in t._fields_
            ],
        }
        for t in WIRE_TYPES
    }


def parse_args(argv):
    repo = Path(__file__).resolve().parents[2]
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--prefix", default="vibrocomp/", help="service-name prefix (ends with /)")
    p.add_argument("--duration-s", type=float, default=4.0, help="data time to stream, s")
    p.add_argument("--out", type=Path, default=Path("results.json"), help="results file")
    p.add_argument(
        "--timeout-s", type=float, default=10.0, help="longest wait for any reply, s"
    )
    p.add_argument(
        "--max-in-flight",
        type=int,
        default=16,
        help="accelerometer blocks sent ahead of their compensated block (1..255)",
    )
    p.add_argument(
        "--passport",
        type=Path,
        default=repo / "config/accelerometers/al-15.toml",
        help="passport whose K1_v_per_g scales the accelerometer outputs",
    )
    p.add_argument(
        "--print-layout", action="store_true", help="print the wire layouts as JSON and exit"
    )
    args = p.parse_args(argv)
    if not args.prefix.endswith("/") or args.prefix.startswith("/"):
        p.error(f"--prefix {args.prefix!r}: must end with '/' and not start with '/'")
    if not 0 < args.duration_s <= 3600:
        p.error(f"--duration-s {args.duration_s}: must be in (0, 3600]")
    if not 1 <= args.max_in_flight < SUBSCRIBER_BUFFER:
        p.error(f"--max-in-flight {args.max_in_flight}: must be 1..{SUBSCRIBER_BUFFER - 1}")
    return args


def main(argv) -> int:
    args = parse_args(argv)
    if args.print_layout:
        print(json.dumps(layout()))
        return 0
    version = metadata.version("iceoryx2")
    if version != ICEORYX2_VERSION:
        print(
            f"rig_client: iceoryx2 {version} is installed, the services use "
            f"{ICEORYX2_VERSION}: {PIP_HINT}",
            file=sys.stderr,
        )
        return 1
    client = None
    try:
        client = Client(args)
        results = client.run()
    except RigError as e:
        print(f"rig_client: {e}", file=sys.stderr)
        return 1
    finally:
        if client is not None:
            client.close()
    args.out.write_text(json.dumps(results, allow_nan=False), encoding="utf-8")
    sent = results["sent"]
    print(
        f"rig_client: sent {sent['vib_blocks']} vib + {sent['accel_blocks']} accel blocks, "
        f"{results['received_blocks']} compensated back, {len(results['estimates'])} "
        f"estimates, {results['wall_s']:.3f} s -> {args.out}",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
