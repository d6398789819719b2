"""The package's lab results against the one schema of the lab's `--json`
(docs/schema/lab-json.schema.json).

The Rust side (shared/vibro-lab/tests/json_schema.rs) holds every variant of the JSON
to the schema both ways and writes those variants to fixtures/lab-json/; here:

- every object of the schema is either a class of `vibrocomp.lab` whose fields are
  exactly the object's properties, or one the package keeps as the JSON's dict (a new
  object must be put in one of the two);
- every variant builds into the classes and gives its JSON back (`to_dict()`);
- a real diagnosis that ends "unexplained" without an empirical correction (the key
  `empirical_none`, once unknown to the package) is read, and is the command line's;
- a result the package cannot read is not lost: the error carries the JSON (`raw`).

Regenerate the fixtures with `VIBROCOMP_BLESS=1 cargo test -p vibro-lab --test
json_schema`.
"""

import csv
import json
import math
import typing
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

import vibrocomp as vc
from vibrocomp import lab
from conftest import REPO

SCHEMA = json.loads((REPO / "docs" / "schema" / "lab-json.schema.json").read_text())
DEFS = SCHEMA["$defs"]
FIXTURES = sorted((Path(__file__).parent / "fixtures" / "lab-json").glob("*.json"))

#: Objects of the schema that are classes of the package.
CLASSES = {
    "Row": lab.Row,
    "Summary": lab.Summary,
    "Group": lab.Group,
    "ByVariable": lab.ByVariable,
    "Comparison": lab.Comparison,
    "Param": lab.Param,
    "Fit": lab.Fit,
    "Candidate": lab.Candidate,
    "Step": lab.Step,
    "Diagnosis": lab.Diagnosis,
    "Added": lab.Added,
}
#: The verdicts, one class (`lab.Verdict`) holding the fields of all four.
VERDICTS = ["VerdictNoise", "VerdictEffect", "VerdictConfounded", "VerdictUnexplained"]
#: Objects the package keeps as the JSON's dicts (any key they get is kept).
AS_DICTS = {
    "WindowSpan", "GroupScale", "PathCounts", "WaveformCounts", "LogSummary", "NotApplicable",
    "Suggestion", "Trend", "LackOfFit", "Budget", "DiagnoseOptions", "StageUse", "BudgetUsed",
    "EmpiricalTerm", "Empirical", "ManifestSummary", "BandClip",
}
#: Definitions that are not objects: a float (null for NaN), the verdicts' union.
NOT_OBJECTS = {"float", "Verdict"}

#: Fields of a class that are not keys of the JSON.
NOT_KEYS = {"Added": {"model"}}


def same(a, b) -> bool:
    """JSON-equal, NaN (the package's) equal to null (the JSON's, for NaN and infinities)."""
    if isinstance(a, float) and (math.isnan(a) or math.isinf(a)):
        return b is None or (isinstance(b, float) and (math.isnan(b) or a == b))
    if a is None and isinstance(b, float):
        return math.isnan(b)
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


def test_every_object_of_the_schema_is_a_class_or_kept_as_a_dict():
    known = set(CLASSES) | set(VERDICTS) | AS_DICTS | NOT_OBJECTS
    assert set(DEFS) == known, (
        f"new in the schema: {sorted(set(DEFS) - known)}; gone from it: {sorted(known - set(DEFS))}"
    )


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_a_class_has_the_objects_properties_as_fields(name):
    cls = CLASSES[name]
    have = {f.name for f in fields(cls)} - NOT_KEYS.get(name, set())
    want = set(DEFS[name]["properties"])
    assert have == want, f"{name}: not in the package {sorted(want - have)}, not in the schema {sorted(have - want)}"


def test_the_verdict_has_every_verdicts_properties():
    want = set().union(*(DEFS[v]["properties"] for v in VERDICTS))
    assert {f.name for f in fields(lab.Verdict)} == want
    kinds = {DEFS[v]["properties"]["verdict"]["const"] for v in VERDICTS}
    assert kinds == {"noise", "effect", "confounded", "unexplained"}


def _refs(node) -> set:
    """The definitions a property refers to (directly, or as the items of a list)."""
    if not isinstance(node, dict):
        return set()
    out = set()
    if "$ref" in node:
        out.add(node["$ref"].rsplit("/", 1)[-1])
    for key in ("items", "anyOf"):
        sub = node.get(key)
        for s in sub if isinstance(sub, list) else [sub]:
            out |= _refs(s)
    return out


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_a_property_that_is_a_class_is_read_into_it(name):
    """`Fit.params` is a list of `Param`, not of dicts: a property whose schema is one
    of the classes (or a list of them) has that class in its type."""
    hints = typing.get_type_hints(CLASSES[name])
    for prop, node in DEFS[name]["properties"].items():
        for target in _refs(node) & set(CLASSES):
            assert CLASSES[target].__name__ in repr(hints[prop]), f"{name}.{prop}: {hints[prop]} is not {target}"


def test_the_fixtures_hold_every_variant():
    assert len(FIXTURES) >= 10, "run `VIBROCOMP_BLESS=1 cargo test -p vibro-lab --test json_schema`"
    docs = [json.loads(f.read_text()) for f in FIXTURES]
    verdicts = {d["json"]["verdict"]["verdict"] for d in docs if d["definition"] == "Diagnosis"}
    assert verdicts == {"noise", "effect", "confounded", "unexplained"}
    diagnoses = [d["json"] for d in docs if d["definition"] == "Diagnosis"]
    assert any("empirical_none" in d for d in diagnoses)
    assert any(d["empirical"] is not None for d in diagnoses)
    assert any("not_applicable" in (c.get("fit") or {}) for d in diagnoses for c in d["candidates"])
    assert {d["definition"] for d in docs} == {"Comparison", "Diagnosis", "Added"}


@pytest.mark.parametrize("path", FIXTURES, ids=[f.stem for f in FIXTURES])
def test_every_variant_builds_and_gives_its_json_back(path):
    doc = json.loads(path.read_text())
    cls = CLASSES[doc["definition"]]
    result = lab._parse(cls, json.dumps(doc["json"]))
    assert isinstance(result, cls)
    assert same(result.to_dict(), doc["json"])
    assert len(repr(result)) < 1000


def test_an_unknown_key_is_an_error_that_keeps_the_result():
    doc = json.loads((Path(__file__).parent / "fixtures" / "lab-json" / "diagnose-effect.json").read_text())
    doc["json"]["candidates"][0]["fit"]["new_key"] = 1
    text = json.dumps(doc["json"])
    with pytest.raises(lab.LabResultError) as e:
        lab._parse(lab.Diagnosis, text)
    assert isinstance(e.value, TypeError)
    assert "new_key" in str(e.value) and "Fit" in str(e.value)
    assert e.value.raw == text
    assert json.loads(e.value.raw)["verdict"]["verdict"] == "effect"


def scrambled_table(path: Path) -> Path:
    """The walkthrough's 14 rows with 3e-4 g (300 uncertainties) of a sign pattern
    added to the measured VE: no effect and no smooth function of the conditions
    follows it (the Rust test's table)."""
    src = REPO / "shared" / "vibro-lab" / "tests" / "data" / "walkthrough-14-rows.csv"
    rows = list(csv.DictReader(src.open()))
    for i, r in enumerate(rows):
        r["ve_measured_g"] = repr(float(r["ve_measured_g"]) + (3e-4 if (i * 7 + 3) % 5 < 2 else -3e-4))
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return path


def without_timing(d: dict) -> dict:
    d = json.loads(json.dumps(d))
    for k in ("elapsed_s", "stages"):
        d["budget"].pop(k, None)
    d["options"].pop("threads", None)
    return d


def test_a_diagnosis_without_an_empirical_correction_is_the_command_lines(cli, tmp_path):
    table = scrambled_table(tmp_path / "scrambled.csv")
    want = cli("lab", "diagnose", table)
    assert want["verdict"]["verdict"] == "unexplained" and "empirical_none" in want
    d = vc.lab.diagnose(table)
    assert d.verdict.verdict == "unexplained"
    assert d.empirical is None and d.empirical_none == want["empirical_none"]
    assert same(without_timing(d.to_dict()), without_timing(want))
    assert "no empirical correction" in repr(d)
