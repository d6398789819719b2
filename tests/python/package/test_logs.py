"""Logs from Python against independent readers: every message of the demo's session
read back per stream and counted against `vibrocomp log info --json` and against the
PyPI `mcap` reader; the values decoded by `mcap-protobuf-support` (message classes
built from the schemas the file carries) equal the arrays bit for bit; the times are
the data timeline; damaged and foreign files are errors, never a crash."""

import keyword
import os
import random
import struct
from collections import defaultdict

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

import vibrocomp as vc

BLOCKS = ("vibrocomp.v1.AccelBlock", "vibrocomp.v1.VibBlock", "vibrocomp.v1.TruthBlock",
          "vibrocomp.v1.CompensatedBlock")
SAMPLE_FIELDS = {
    "vibrocomp.v1.AccelBlock": ("output_v",),
    "vibrocomp.v1.VibBlock": ("sample_v",),
    "vibrocomp.v1.TruthBlock": ("a_l_ia_g", "a_sensed_ia_g", "vib_error_ia_g"),
    "vibrocomp.v1.CompensatedBlock": ("a1_g", "a2_g", "a3_g", "a4_g", "main_g", "det_g", "rand_g"),
}


def reference(path):
    """Every message of every channel, decoded by the Python readers, by topic."""
    out = defaultdict(list)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()], validate_crcs=True)
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            out[channel.topic].append((schema.name, message, decoded))
    return out


def bits(a):
    return np.asarray(a, dtype=np.float64).view(np.uint64)


@pytest.fixture(scope="module")
def session(demo_dir):
    path = demo_dir / "session.mcap"
    return path, vc.Log(path), reference(path)


def test_every_message_of_every_stream_is_read_and_counted(cli, session):
    path, log, ref = session
    info = cli("log", "info", path)
    assert log.info == info
    total = 0
    for ch in info["channels"]:
        s = log.stream(ch["topic"])
        assert s.kind == ch["message_type"]
        assert len(s) == ch["messages"] == len(ref[ch["topic"]]), ch["topic"]
        total += len(s)
        # The MCAP header of each message: data time, receive time, sequence.
        msgs = [m for _, m, _ in ref[ch["topic"]]]
        assert np.array_equal(s.rows["log_time_ns"], [m.log_time for m in msgs])
        assert np.array_equal(s.rows["publish_time_ns"], [m.publish_time for m in msgs])
        assert np.array_equal(s.rows["sequence"], [m.sequence for m in msgs])
    assert total == info["messages"] == sum(len(v) for v in ref.values())


def test_block_samples_are_the_protobuf_values_on_the_data_timeline(session):
    path, log, ref = session
    for topic, kind in log.topics.items():
        if kind not in BLOCKS:
            continue
        s = log.stream(topic)
        decoded = [d for _, _, d in ref[topic]]
        counts = [len(getattr(d, SAMPLE_FIELDS[kind][0])) // 3 for d in decoded]
        assert np.array_equal(s.rows["count"], counts)
        n = sum(counts)
        assert len(s.samples["t_ns"]) == n
        for name in SAMPLE_FIELDS[kind]:
            want = np.concatenate([np.asarray(getattr(d, name), dtype=np.float64) for d in decoded])
            assert np.array_equal(bits(s.samples[name].reshape(-1)), bits(want)), (topic, name)
        t = np.concatenate([d.t0_ns + np.arange(c, dtype=np.uint64) * d.sample_period_ns
                            for d, c in zip(decoded, counts)])
        assert np.array_equal(s.samples["t_ns"], t)
        idx = np.concatenate([d.first_sample_index + np.arange(c, dtype=np.uint64) for d, c in zip(decoded, counts)])
        assert np.array_equal(s.samples["sample_index"], idx)
        assert np.array_equal(s.samples["flags"], np.repeat([d.flags for d in decoded], counts))
        assert np.array_equal(s.rows["seq"][s.samples["block"]], np.repeat([d.seq for d in decoded], counts))
        # A block's data time (its log time) is its last sample's time.
        last = np.cumsum(counts) - 1
        assert np.array_equal(s.samples["t_ns"][last], s.rows["log_time_ns"])
    comp = log.stream("/compensated")
    decoded = [d for _, _, d in ref["/compensated"]]
    assert np.array_equal(comp.rows["mode"], [d.mode for d in decoded])
    assert np.array_equal(comp.rows["estimate_age_ns"], [d.estimate_age_ns for d in decoded])
    frame = comp.to_frame()
    assert len(frame) == len(comp.samples["t_ns"]) and "a4_g_2" in frame.columns


def test_estimates_are_the_protobuf_values_with_nan_beyond_the_counts(session):
    path, log, ref = session
    e = log.stream("/estimate")
    for i, (_, _, d) in enumerate(ref["/estimate"]):
        assert e.rows["tone_count"][i] == len(d.tones) and e.rows["band_count"][i] == len(d.bands)
        for j, t in enumerate(d.tones):
            assert bits(e.rows["tone_frequency_hz"][i, j]) == bits(t.frequency_hz)
            assert np.array_equal(bits(e.rows["tone_amplitude_g"][i, j]), bits(t.amplitude_g))
            assert np.array_equal(bits(e.rows["tone_phase_rad"][i, j]), bits(t.phase_rad))
        assert np.isnan(e.rows["tone_frequency_hz"][i, len(d.tones):]).all()
        for j, b in enumerate(d.bands):
            assert np.array_equal(bits(e.rows["band_psd_g2_per_hz"][i, j]), bits(b.psd_g2_per_hz))
        assert np.isnan(e.rows["band_psd_g2_per_hz"][i, len(d.bands):]).all()
        assert np.array_equal(bits(e.rows["broadband_rms_g"][i]), bits(d.broadband.rms_g))
        assert np.array_equal(bits(e.rows["broadband_covariance_g2"][i].reshape(-1)), bits(d.broadband.covariance_g2))
        assert (e.rows["start_ns"][i], e.rows["end_ns"][i], e.rows["seq"][i]) == (d.start_ns, d.end_ns, d.seq)


def test_view_channels_heartbeats_and_log_lines_are_the_protobuf_values(session):
    path, log, ref = session
    v = log.stream("/view/AK1")
    for i, (_, _, d) in enumerate(ref["/view/AK1"]):
        assert v.rows["unit"][i] == d.unit and v.rows["samples"][i] == d.samples
        assert v.rows["t_ns"][i] == d.timestamp.seconds * 10**9 + d.timestamp.nanos
        for stage in ("uncompensated_g", "compensated_g", "reference_g", "compensated_error_g"):
            if d.HasField(stage):
                got = [v.rows[f"{stage}_{x}"][i] for x in ("mean", "min", "max")]
                want = [getattr(getattr(d, stage), x) for x in ("mean", "min", "max")]
                assert np.array_equal(bits(got), bits(want)), stage
            else:
                assert np.isnan(v.rows[f"{stage}_mean"][i])
    h = log.stream("/heartbeat/estimator")
    assert list(h.rows["received"]) == [d.received for _, _, d in ref["/heartbeat/estimator"]]
    lines = log.stream("/log/estimator")
    assert list(lines.rows["text"]) == [d.text for _, _, d in ref["/log/estimator"]]
    fox = log.stream("/log")
    assert list(fox.rows["message"]) == [d.message for _, _, d in ref["/log"]]
    health = log.stream("/view/health/compensator")
    assert list(health.rows["state"]) == [type(d).State.Name(d.state) for _, _, d in ref["/view/health/compensator"]]


def test_metadata_attachments_and_the_rig_description(session, demo_dir):
    path, log, ref = session
    meta = log.metadata
    assert meta["recording"]["topics"].startswith("/vib")
    with open(path, "rb") as f:
        r = make_reader(f)
        want = {a.name: (a.media_type, a.data) for a in r.iter_attachments()}
    got = log.attachments
    assert {k: (a.media_type, a.data) for k, a in got.items()} == want
    passport = got["passport-0-AL-15.toml"].toml()
    assert passport["id"] == "AL-15" and passport["k2_ppm_per_g"] == 105.0
    flight = vc.Log(demo_dir / "flight.mcap")
    assert flight.rig["name"] == "cyclone-4-short" and flight.rig["units"] == "AK1, AK2, AK3"


def test_damaged_and_foreign_files_are_errors_never_a_crash(session, tmp_path):
    path, log, ref = session
    with pytest.raises(vc.VibrocompError) as e:
        log.stream("/no/such/topic")
    assert "no channel on topic" in str(e.value)
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("not a log\n")
    with pytest.raises(vc.VibrocompError) as e:
        vc.Log(not_mcap)
    assert e.value.file is None or e.value.file == str(not_mcap)
    with pytest.raises(vc.VibrocompError):
        vc.Log(tmp_path / "missing.mcap")
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(vc.VibrocompError, match="not finished|recover"):
        vc.Log(cut)
    # Flipped bytes anywhere: every outcome is data or a VibrocompError.
    rng = random.Random(7)
    outcomes = defaultdict(int)
    damaged = tmp_path / "damaged.mcap"
    for _ in range(40):
        b = bytearray(data)
        for _ in range(8):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        damaged.write_bytes(bytes(b))
        try:
            d = vc.Log(damaged)
            for topic in ("/accel", "/estimate", "/view/AK1"):
                d.stream(topic)
            outcomes["read"] += 1
        except vc.VibrocompError:
            outcomes["refused"] += 1
    assert sum(outcomes.values()) == 40 and outcomes["refused"] > 0, dict(outcomes)


def test_a_stream_without_messages_has_the_columns_of_any_other(session, tmp_path):
    """A channel that never got a message (a service that logged nothing) reads as
    zero rows with the same columns, found by a log the demo happened to make."""
    from mcap.writer import Writer

    path, log, ref = session
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    by_topic = {c.topic: (summary.schemas[c.schema_id], c) for c in summary.channels.values()}
    empty = tmp_path / "empty-channels.mcap"
    with open(empty, "wb") as f:
        w = Writer(f)
        w.start(profile="vibrocomp", library="test")
        for topic in ("/log/estimator", "/accel", "/estimate", "/view/AK1"):
            schema, channel = by_topic[topic]
            sid = w.register_schema(schema.name, schema.encoding, schema.data)
            w.register_channel(topic, channel.message_encoding, sid)
        w.finish()
    e = vc.Log(empty)
    for topic in ("/log/estimator", "/accel", "/estimate", "/view/AK1"):
        got, full = e.stream(topic), log.stream(topic)
        assert len(got) == 0 and list(got.rows) == list(full.rows), topic
        assert all(np.shape(got.rows[k])[1:] == np.shape(full.rows[k])[1:] for k in got.rows)
        if full.samples is not None:
            assert list(got.samples) == list(full.samples)


def test_opening_a_log_reads_its_summary_only(session, tmp_path):
    """Opening reads no chunk (a 600 s log opens at once); a damaged chunk is found
    by what reads it. Found by the read benchmark: opening used to read every chunk."""
    path, log, ref = session
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    chunk = max(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    data = bytearray(path.read_bytes())
    # The last byte of the chunk's compressed records: its CRC or its zstd frame fails.
    data[chunk.chunk_start_offset + chunk.chunk_length - 1] ^= 0xFF
    damaged = tmp_path / "damaged-chunk.mcap"
    damaged.write_bytes(bytes(data))
    d = vc.Log(damaged)
    assert d.topics == log.topics
    with pytest.raises(vc.VibrocompError):
        d.info
    topic = next(summary.channels[c].topic for c in chunk.message_index_offsets)
    with pytest.raises(vc.VibrocompError):
        d.stream(topic)


def test_integers_are_int64_so_that_differences_are_signed(session):
    """Times, indices and counters are int64 (a difference of two times is negative
    where it should be, never a uint64 wrapped to 1.8e19); the `flags` bit fields
    uint32; values the `mcap` reader's."""
    path, log, ref = session
    for topic in log.topics:
        s = log.stream(topic)
        for table in (s.samples, s.rows):
            for name, a in table.items():
                if a.dtype.kind in "iu":
                    want = np.uint32 if name == "flags" else np.int64
                    assert a.dtype == want, (topic, name, a.dtype)
                if name.endswith("_ns"):
                    assert a.dtype == np.int64, (topic, name, a.dtype)
    accel = log.stream("/accel")
    decoded = [d for _, _, d in ref["/accel"]]
    t = accel.samples["t_ns"]
    assert t[0] - t[1] == -decoded[0].sample_period_ns < 0
    last = decoded[-1]
    assert t[0] == decoded[0].t0_ns
    assert t[-1] == last.t0_ns + (len(last.output_v) // 3 - 1) * last.sample_period_ns
    log_time = accel.rows["log_time_ns"]
    assert (np.diff(log_time[::-1]) < 0).all()
    first_message, last_message = ref["/accel"][0][1], ref["/accel"][-1][1]
    assert log_time[0] - log_time[-1] == first_message.log_time - last_message.log_time < 0
    frame = accel.to_frame()
    assert frame["t_ns"].dtype == np.int64 and frame["sample_index"].dtype == np.int64


def test_frame_columns_are_identifiers_with_the_readers_values(session):
    """`to_frame` names an (N, 3) column's parts `name_0 .. name_2` and an (N, k, 3)
    one's `name_j_u`: attributes of the frame, with the protobuf values."""
    path, log, ref = session
    comp = log.stream("/compensated")
    frame = comp.to_frame()
    assert all(c.isidentifier() and not keyword.iskeyword(c) for c in frame.columns), list(frame.columns)
    decoded = [d for _, _, d in ref["/compensated"]]
    for u in range(3):
        want = np.concatenate([np.asarray(d.a4_g, dtype=np.float64)[u::3] for d in decoded])
        assert np.array_equal(bits(getattr(frame, f"a4_g_{u}")), bits(want))
    est = log.stream("/estimate")
    rows = est.to_frame("rows")
    assert all(c.isidentifier() and not keyword.iskeyword(c) for c in rows.columns), list(rows.columns)
    for i, (_, _, d) in enumerate(ref["/estimate"]):
        for j, tone in enumerate(d.tones):
            assert bits(rows[f"tone_amplitude_g_{j}_2"].iloc[i]) == bits(tone.amplitude_g[2])
        assert bits(rows.broadband_covariance_g2_2_0.iloc[i]) == bits(d.broadband.covariance_g2[6])
    assert list(log.stream("/log").to_frame().message) == [d.message for _, _, d in ref["/log"]]
    with pytest.raises(ValueError, match="what = 'sample'"):
        est.to_frame("sample")


def one_message_log(path, session_path, topic, edit, log_time=None):
    """A log holding the first message of `topic` in `session_path`, its decoded
    protobuf changed by `edit` (and its log time by `log_time`)."""
    from mcap.writer import Writer

    with open(session_path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        schema, channel, message, decoded = next(reader.iter_decoded_messages(topics=[topic]))
    edit(decoded)
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="vibrocomp", library="test")
        sid = w.register_schema(schema.name, schema.encoding, schema.data)
        cid = w.register_channel(topic, channel.message_encoding, sid)
        w.add_message(cid, log_time=message.log_time if log_time is None else log_time,
                      data=decoded.SerializeToString(), publish_time=message.publish_time, sequence=7)
        w.finish()
    return path


def test_values_beyond_int64_are_refused_and_negative_times_kept(session, tmp_path):
    """Nanoseconds since the epoch fit an int64 for 292 years: a time beyond (a damaged
    or forged field) is refused, naming it, never wrapped or clipped; a time before the
    epoch is negative, as it is."""
    path, log, ref = session
    cases = [
        ("/accel", lambda d: setattr(d, "t0_ns", 2**63), None, "t0_ns = 9223372036854775808"),
        ("/accel", lambda d: setattr(d, "t0_ns", 2**63 - 5), None,
         "t_ns of its last sample = t0_ns 9223372036854775803 + "),
        ("/estimate", lambda d: setattr(d, "end_ns", 2**64 - 1), None, "end_ns = 18446744073709551615"),
        ("/accel", lambda d: None, 2**63 + 1, "log_time_ns = 9223372036854775809"),
    ]
    for i, (topic, edit, log_time, what) in enumerate(cases):
        bad = one_message_log(tmp_path / f"beyond-{i}.mcap", path, topic, edit, log_time)
        with pytest.raises(vc.VibrocompError) as e:
            vc.Log(bad).stream(topic)
        msg = str(e.value)
        assert f"{topic} message 7: {what}" in msg and "beyond the int64 columns" in msg, msg
        assert "9223372036854775807" in msg, msg

    def before_epoch(d):
        d.timestamp.seconds, d.timestamp.nanos = -2, 5

    early = one_message_log(tmp_path / "early.mcap", path, "/view/AK1", before_epoch)
    assert vc.Log(early).stream("/view/AK1").rows["t_ns"].tolist() == [-2 * 10**9 + 5]
