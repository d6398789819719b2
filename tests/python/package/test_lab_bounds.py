"""The lab's table bounds from Python ("Reliability, round four", item 2): the package
reads a file, a DataFrame or a dict of arrays with the command line's one reader
(`vibro_lab::table_input`), so `/dev/zero`, a line over the 64 KiB cap, more than 64
columns or a million rows are refused as on the command line (the same message), and
repeated conditions are evaluated once (`summary.distinct_conditions`)."""

import pytest

import vibrocomp as vc

HEADER = [
    "run_id", "passport", "aL1_g", "aL2_g", "aL3_g", "freq_hz", "aB1_g", "aB2_g", "aB3_g",
    "phase31_deg", "phase32_deg", "sigma1_g", "sigma2_g", "sigma3_g", "cov31_g2", "cov32_g2",
    "kurtosis3", "ve_measured_g", "ve_uncertainty_g",
]


def row(i):
    return f"R{i},AL-15,0,0,1,30,0,0,0.42,,,,,,,,,1.3e-5,1e-7"


def columns(n, extras=0):
    """A dict of arrays: `n` rows of `row(0)` (one list slot each: a million rows take
    tens of MB), and `extras` columns of zeros."""
    out = {name: [cell] * n for name, cell in zip(HEADER, row(0).split(","))}
    for k in range(extras):
        out[f"x{k}"] = [0.0] * n
    return out


def test_dev_zero_is_refused_at_the_cap_on_a_line(cli):
    with pytest.raises(vc.VibrocompError) as e:
        vc.lab.compare("/dev/zero")
    message = str(e.value)
    assert "/dev/zero: line 1: longer than 65536 bytes (the cap on a line" in message
    assert len(message) < 1024
    want = cli("lab", "compare", "/dev/zero", check=False)["error"]["message"]
    assert message.endswith(want.split("lab compare: ", 1)[1])


def test_a_line_over_the_cap_in_a_file_is_refused_by_its_number(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text(",".join(HEADER) + "\n" + row(0) + "\n" + "7" * (1 << 20) + "\n")
    with pytest.raises(vc.VibrocompError, match=r"t\.csv: line 3: longer than 65536 bytes") as e:
        vc.lab.diagnose(path)
    assert len(str(e.value)) < 1024


def test_a_dict_with_too_many_columns_is_refused():
    with pytest.raises(vc.VibrocompError, match=r"<table 0>: line 1 \(header\): 65 columns: at most 64"):
        vc.lab.compare(columns(2, extras=46))


def test_a_dict_of_a_million_and_one_rows_is_refused_at_the_limit():
    with pytest.raises(vc.VibrocompError, match=r"line 1000002: row 1000001: at most 1000000 rows"):
        vc.lab.compare(columns(1_000_001))


def test_repeated_conditions_are_one_to_the_fits():
    c = vc.lab.compare(columns(1000))
    assert (c.summary.n, c.summary.distinct_conditions) == (1000, 1)
