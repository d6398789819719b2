"""The lab's results in a notebook: a short `repr` (the verdict, the effects found,
chi2/dof; a few lines), HTML tables for Jupyter (`_repr_html_`, every text escaped),
and the candidates and steps as pandas DataFrames whose values are the command line's
`--json` for the same input.

The diagnosis is the largest real one of the package's tests: the walkthrough's
campaign of 200 rows (its `--json` is about 250 kB)."""

import json
import math
from html.parser import HTMLParser
from pathlib import Path

import pytest

import vibrocomp as vc
from vibrocomp import lab
from conftest import REPO

CAMPAIGN = REPO / "examples" / "python" / "data" / "campaign-mount-k6.csv"
FIXTURES = Path(__file__).parent / "fixtures" / "lab-json"
#: The bound on a result's repr, characters.
REPR_MAX = 1000


@pytest.fixture(scope="module")
def diagnosed(cli):
    """The package's diagnosis of the campaign and the command line's `--json`."""
    return vc.lab.diagnose(CAMPAIGN), cli("lab", "diagnose", CAMPAIGN)


class Page(HTMLParser):
    """The text and tags of an HTML fragment; `problems` lists end tags that close
    nothing open and tags left open."""

    VOID = {"br", "hr", "img", "meta", "col"}

    def __init__(self, text: str):
        super().__init__(convert_charrefs=True)
        self.text, self.tags, self.open, self.problems = [], [], [], []
        self.feed(text)
        self.close()
        self.problems += [f"<{t}> not closed" for t in self.open]

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag not in self.VOID:
            self.open.append(tag)

    def handle_endtag(self, tag):
        if not self.open or self.open[-1] != tag:
            self.problems.append(f"</{tag}> closes {self.open[-1:] or 'nothing'}")
        else:
            self.open.pop()

    def handle_data(self, data):
        self.text.append(data)

    @property
    def all_text(self) -> str:
        return " ".join(self.text)


def test_the_diagnosis_repr_is_short_and_says_the_verdict(diagnosed):
    d, want = diagnosed
    assert len(json.dumps(want)) > 100_000
    r = repr(d)
    assert len(r) < REPR_MAX, len(r)
    assert len(r.splitlines()) <= 6
    assert want["verdict"]["verdict"] in r
    for kind in want["selected"]["kinds"]:
        assert kind in r
    s = want["comparison"]["summary"]
    assert f"{s['chi2_per_dof']:.4g}" in r
    assert f"{want['selected']['chi2_per_dof_after']:.4g}" in r


def test_every_result_of_the_diagnosis_has_a_short_repr(diagnosed):
    d, _ = diagnosed
    parts = [d, d.comparison, d.selected, d.verdict, d.comparison.summary, *d.candidates, *d.steps,
             *d.comparison.rows[:5], *d.selected.params]
    for p in parts:
        assert len(repr(p)) < REPR_MAX, (type(p).__name__, len(repr(p)))


def test_the_added_repr_is_short(cli, tmp_path):
    a = vc.lab.add(["mount_resonance"], CAMPAIGN)
    r = repr(a)
    assert len(r) < REPR_MAX and "mount_resonance" in r and "Model(" in r
    page = Page(a._repr_html_())
    assert not page.problems and "mount_resonance" in page.all_text


def test_the_diagnosis_html_parses_and_holds_the_verdict_and_the_effects(diagnosed):
    d, want = diagnosed
    page = Page(d._repr_html_())
    assert not page.problems, page.problems
    assert "table" in page.tags
    text = page.all_text
    assert want["verdict"]["verdict"] in text
    for kind in want["selected"]["kinds"]:
        assert kind in text
    for c in want["candidates"]:
        assert c["kind"] in text
    for st in want["steps"]:
        assert st["action"] in text
    for obj in (d.comparison, d.selected):
        p = Page(obj._repr_html_())
        assert not p.problems and "table" in p.tags


def test_the_html_escapes_what_it_shows():
    doc = json.loads((FIXTURES / "diagnose-effect.json").read_text())["json"]
    hostile = "<script>alert('x')</script> & <marquee>"
    doc["candidates"][0]["kind"] = hostile
    doc["verdict"]["kinds"] = [hostile]
    doc["comparison"]["rows"][0]["run_id"] = hostile
    d = lab._parse(lab.Diagnosis, json.dumps(doc))
    for html in (d._repr_html_(), d.comparison._repr_html_()):
        page = Page(html)
        assert "script" not in page.tags and "marquee" not in page.tags, page.tags
        assert hostile in page.all_text
        assert not page.problems


def same(a, b) -> bool:
    if isinstance(a, float) and math.isnan(a):
        return b is None or (isinstance(b, float) and math.isnan(b))
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


def test_the_candidates_frame_is_the_command_lines_candidates(diagnosed):
    d, want = diagnosed
    frame = d.to_frame("candidates")
    assert frame.equals(d.candidates_frame())
    assert len(frame) == len(want["candidates"])
    for (_, row), c in zip(frame.iterrows(), want["candidates"]):
        for key in ("kind", "physics", "signature", "supported", "explains", "not_applicable"):
            assert same(row[key], c[key]), key
        fit = c["fit"]
        for key in ("delta_bic", "chi2_after", "chi2_per_dof_after", "p_value_after", "bic_after",
                    "rms_residual_after_g", "n", "k", "evaluations"):
            assert same(row[key], math.nan if fit is None else fit[key]), (c["kind"], key)
        params = {} if fit is None else {f"{p['effect']}.{p['name']}": p["value"] for p in fit["params"]}
        assert row["params"] == params
    assert any(c["fit"] is not None for c in want["candidates"])


def test_the_steps_frame_is_the_command_lines_steps(diagnosed):
    d, want = diagnosed
    frame = d.to_frame("steps")
    assert list(frame.columns) == list(want["steps"][0])
    assert len(frame) == len(want["steps"])
    for (_, row), st in zip(frame.iterrows(), want["steps"]):
        for key, value in st.items():
            assert same(row[key], value), key


def test_the_rows_frame_is_the_comparisons_and_a_wrong_name_is_refused(diagnosed):
    d, want = diagnosed
    rows = d.to_frame("rows")
    assert list(rows["run_id"]) == [r["run_id"] for r in want["comparison"]["rows"]]
    assert list(rows["residual_g"]) == [r["residual_g"] for r in want["comparison"]["rows"]]
    with pytest.raises(ValueError, match="candidates"):
        d.to_frame("nothing")


def test_the_fits_frame_is_its_parameters(diagnosed):
    d, want = diagnosed
    frame = d.selected.to_frame()
    assert list(frame["value"]) == [p["value"] for p in want["selected"]["params"]]
    assert list(frame["name"]) == [p["name"] for p in want["selected"]["params"]]


def test_the_archive_summary_repr_is_one_short_line():
    s = vc.archive.ArchiveSummary(
        manifest=Path("m.toml"), out_dir=Path("out"), jobs_total=12, done_now=9, skipped=2, failed=1,
        pending=0, duplicates=0, torn_bytes=0, rows=340, results=Path("out/results.parquet"),
        report=Path("out/report.html"), journal=Path("out/journal.jsonl"), elapsed_s=12.34,
        scheduler="local:2",
    )
    r = repr(s)
    assert "\n" not in r and len(r) < 200, r
    for part in ("12 jobs", "9 done now", "2 skipped", "1 failed", "0 pending", "340 rows", "12.3 s", "local:2"):
        assert part in r
