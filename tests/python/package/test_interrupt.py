"""Long calls can be stopped: Ctrl-C (SIGINT) stops a diagnosis within 0.5 s with
`KeyboardInterrupt`, an exception raised by the `progress` callback ends the call at
once with that exception (no traceback printed, no result), `progress` is called at
least every 0.5 s while a call runs, and a notebook gets a tqdm bar by default."""

import signal
import subprocess
import sys
import textwrap
import time
import types

import pytest

import vibrocomp as vc
import vibrocomp.lab as lab
from conftest import REPO

CAMPAIGN = REPO / "examples" / "python" / "data" / "campaign-mount-k6.csv"

# _CTRL_C: the scripts below install Python's own SIGINT handler, as an interactive
# session has it. A process started with SIGINT ignored (a background job of a
# non-interactive shell, `cmd &`, runs so) passes that on to its children, and Python
# keeps an inherited SIG_IGN: the child would never see the Ctrl-C this test sends.


@pytest.fixture(scope="module")
def long_table(tmp_path_factory):
    """The walkthrough's campaign three times over (its runs renamed): a diagnosis of a
    few seconds."""
    lines = CAMPAIGN.read_text().splitlines()
    comments = [line for line in lines if line.startswith("#")]
    header, *rows = [line for line in lines if not line.startswith("#")]
    out = comments + [header]
    for k in range(3):
        for row in rows:
            run_id, rest = row.split(",", 1)
            out.append(f"{run_id}-{k},{rest}")
    path = tmp_path_factory.mktemp("long") / "campaign-x3.csv"
    path.write_text("\n".join(out) + "\n")
    return path


@pytest.fixture(scope="module")
def full_s(long_table):
    """How long the whole diagnosis takes here, s (the tests need it to be long)."""
    t0 = time.monotonic()
    vc.lab.diagnose(long_table, progress=False)
    s = time.monotonic() - t0
    if s < 1.0:
        pytest.skip(f"the diagnosis takes {s:.2f} s here: too short to stop half way")
    return s


def test_ctrl_c_stops_a_diagnosis_within_half_a_second(long_table, full_s):
    script = textwrap.dedent(
        f"""
        import signal, sys, time
        signal.signal(signal.SIGINT, signal.default_int_handler)  # see _CTRL_C
        import vibrocomp as vc
        print("start", flush=True)
        try:
            vc.lab.diagnose({str(long_table)!r}, progress=False)
            print("finished", time.monotonic(), flush=True)
        except KeyboardInterrupt:
            print("interrupted", time.monotonic(), flush=True)
        """
    )
    p = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "start"
        # Well into the fits (the import and the table's reading done).
        time.sleep(min(1.0, full_s / 3))
        sent = time.monotonic()
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
    finally:
        p.kill()
    what, when = out.split()
    latency_s = float(when) - sent
    print(f"KeyboardInterrupt {latency_s * 1e3:.0f} ms after SIGINT (whole diagnosis {full_s:.1f} s)")
    assert what == "interrupted", (out, err)
    assert latency_s < 0.5, f"KeyboardInterrupt {latency_s:.3f} s after SIGINT"
    assert "Traceback" not in err, err


class Enough(Exception):
    pass


def test_an_exception_in_progress_ends_the_call_with_it(long_table, full_s, capfd):
    calls = []

    def progress(done, of, what):
        calls.append(time.monotonic())
        if len(calls) == 3:
            raise Enough(f"stop at {done} of {of} ({what})")

    t0 = time.monotonic()
    with pytest.raises(Enough):
        vc.lab.diagnose(long_table, progress=progress)
    ended = time.monotonic()
    assert len(calls) == 3, "the callback is not called again after it raised"
    assert ended - calls[-1] < 0.5, f"the call ended {ended - calls[-1]:.3f} s after the exception"
    assert ended - t0 < full_s / 2
    out, err = capfd.readouterr()
    assert "Traceback" not in err and "Enough" not in err, err
    # The lab's threads stopped too: the process is idle after the call.
    cpu_s = time.process_time()
    time.sleep(0.5)
    assert time.process_time() - cpu_s < 0.1, "the fits go on behind the exception"


def test_progress_is_called_at_least_every_half_second(long_table, full_s):
    calls = []
    t0 = time.monotonic()
    d = vc.lab.diagnose(long_table, progress=lambda done, of, what: calls.append((time.monotonic(), done, of, what)))
    t1 = time.monotonic()
    times = [t0] + [c[0] for c in calls] + [t1]
    gaps = [b - a for a, b in zip(times, times[1:])]
    assert max(gaps) <= 0.5, f"{max(gaps):.3f} s without a call of progress"
    assert all(isinstance(c[1], int) and isinstance(c[2], int) and isinstance(c[3], str) for c in calls)
    # The last call: every candidate of the last round fitted; the diagnosis is whole.
    assert calls[-1][1] == calls[-1][2] > 0 and d.next_effects


class FakeBar:
    made = []

    def __init__(self, **kwargs):
        self.kwargs, self.n, self.total, self.desc, self.closed = kwargs, 0, None, "", False
        self.seen = []
        FakeBar.made.append(self)

    def reset(self, total=None):
        self.total, self.n = total, 0

    def set_description_str(self, desc, refresh=True):
        self.desc = desc

    def refresh(self):
        self.seen.append((self.n, self.total, self.desc))

    def close(self):
        self.closed = True


@pytest.fixture
def fake_tqdm(monkeypatch):
    FakeBar.made = []
    auto = types.ModuleType("tqdm.auto")
    auto.tqdm = FakeBar
    monkeypatch.setitem(sys.modules, "tqdm.auto", auto)
    return FakeBar


def test_a_notebook_gets_a_tqdm_bar_by_default_and_progress_false_none(monkeypatch, fake_tqdm):
    monkeypatch.setattr(lab, "_in_notebook", lambda: True)
    vc.lab.diagnose(CAMPAIGN, effects=["mount_resonance", "heating"])
    [bar] = fake_tqdm.made
    # Counts faster than the calling thread's tick (0.1 s) are seen as the latest.
    assert bar.closed and bar.seen[-1][0] == bar.seen[-1][1] > 0, bar.seen
    vc.lab.diagnose(CAMPAIGN, effects=["heating"], progress=False)
    assert len(fake_tqdm.made) == 1, "progress=False: no bar"
    monkeypatch.setattr(lab, "_in_notebook", lambda: False)
    vc.lab.compare(CAMPAIGN)
    assert len(fake_tqdm.made) == 1, "no bar outside a notebook by default"
    vc.lab.compare(CAMPAIGN, progress=True)
    assert len(fake_tqdm.made) == 2 and fake_tqdm.made[-1].closed


def test_a_notebook_is_an_ipython_kernel(monkeypatch):
    monkeypatch.delitem(sys.modules, "IPython", raising=False)
    assert not lab._in_notebook()
    shell = types.SimpleNamespace(config={})
    ipython = types.ModuleType("IPython")
    ipython.get_ipython = lambda: shell
    monkeypatch.setitem(sys.modules, "IPython", ipython)
    assert not lab._in_notebook(), "a terminal IPython is not a notebook"
    shell.config = {"IPKernelApp": {"connection_file": "kernel.json"}}
    assert lab._in_notebook()


def test_the_real_tqdm_draws_the_bar(capsys):
    pytest.importorskip("tqdm")
    vc.lab.diagnose(CAMPAIGN, effects=["mount_resonance", "heating"], progress=True)
    err = capsys.readouterr().err
    assert "100%" in err, err


def test_a_progress_that_is_not_callable_is_refused():
    with pytest.raises(TypeError, match="progress = 3"):
        vc.lab.compare(CAMPAIGN, progress=3)


@pytest.fixture(scope="module")
def long_log(tmp_path_factory):
    """A 400 s simulated flight (129 MB): its /vib stream takes about a second to read."""
    from conftest import binary

    exe = binary()
    if not exe.is_file():
        pytest.skip(f"{exe} is missing")
    out = tmp_path_factory.mktemp("long-log") / "flight.mcap"
    subprocess.run([str(exe), "-q", "sim", "cyclone-4", "--duration-s", "400", "--out", str(out)],
                   check=True, capture_output=True, cwd=REPO)
    return out


def test_ctrl_c_stops_reading_a_log_and_the_reading_behind_it(long_log):
    """`Log.stream` raises `KeyboardInterrupt` at once, and the reading on its own
    thread stops at its next message: the process is idle after the exception."""
    script = textwrap.dedent(
        f"""
        import signal, sys, time
        signal.signal(signal.SIGINT, signal.default_int_handler)  # see _CTRL_C
        import vibrocomp as vc
        log = vc.Log({str(long_log)!r})
        t0 = time.monotonic()
        log.stream("/vib")
        full_s = time.monotonic() - t0
        print("start", full_s, flush=True)
        try:
            log.stream("/vib")
            print("finished", time.monotonic(), 0.0, flush=True)
        except KeyboardInterrupt:
            at = time.monotonic()
            cpu_s = time.process_time()
            time.sleep(0.5)
            print("interrupted", at, time.process_time() - cpu_s, flush=True)
        """
    )
    p = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        what, full_s = p.stdout.readline().split()
        assert what == "start"
        if float(full_s) < 0.6:
            pytest.skip(f"reading the stream takes {float(full_s):.2f} s here: too short to stop")
        time.sleep(float(full_s) / 5)  # most of the reading still ahead
        sent = time.monotonic()
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        p.kill()
    what, when, cpu_after_s = out.split()
    print(f"KeyboardInterrupt {(float(when) - sent) * 1e3:.0f} ms after SIGINT; "
          f"CPU in the 0.5 s after it {float(cpu_after_s):.3f} s (whole read {float(full_s):.2f} s)")
    assert what == "interrupted", (out, err)
    assert float(when) - sent < 0.5
    assert float(cpu_after_s) < 0.05, "the reading goes on behind the exception"
