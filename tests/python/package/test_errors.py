"""Errors from Python against the command line: every bad input raises the subclass of
`VibrocompError` a caller would catch (a missing file is a `FileNotFoundError`, a bad
value or key a `ValueError`, ...), with the file, line, column and key of the command
line's `--json` error object for the same input, and its message; log errors name
their file, a text file given to the lab as a log is "not an MCAP log", hints name the
command (`vibrocomp log recover`), not a Rust function."""

import errno
import os
import pickle

import pytest

import vibrocomp as vc
import vibrocomp.errors as ve
from conftest import REPO

CAMPAIGN = REPO / "examples" / "python" / "data" / "campaign-mount-k6.csv"
FIELDS = ("file", "line", "column", "key")


@pytest.fixture(scope="module")
def bad(tmp_path_factory):
    """The bad inputs, made once: each a file named for its problem."""
    d = tmp_path_factory.mktemp("bad")
    (d / "notes.mcap").write_text("not a log\n")
    (d / "notes.txt").write_text("not a log\n")
    lines = CAMPAIGN.read_text().splitlines()
    cells = lines[6].split(",")
    cells[18] = "-1"  # line 7: an impossible uncertainty
    lines[6] = ",".join(cells)
    (d / "row.csv").write_text("\n".join(lines) + "\n")
    (d / "model-key.toml").write_text('mode = "exact"\nbogus = 3\n')
    (d / "passport-key.toml").write_text('id = "X"\nbogus_key = 1\n')
    (d / "folder.mcap").mkdir()
    (d / "folder.csv").mkdir()
    return d


@pytest.fixture(scope="module")
def cut_log(demo_dir, tmp_path_factory):
    """The demo's session log cut in half (a crash of its recorder)."""
    data = (demo_dir / "session.mcap").read_bytes()
    cut = tmp_path_factory.mktemp("cut") / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    return cut


def raised(call):
    with pytest.raises(vc.VibrocompError) as e:
        call()
    return e.value


# --- one test per defect of the issue ---------------------------------------------


def test_a_missing_file_is_a_FileNotFoundError_with_the_os_error_once(tmp_path):
    for call, path in [
        (vc.lab.compare, tmp_path / "missing.csv"),
        (vc.lab.compare, tmp_path / "missing.mcap"),
        (vc.Log, tmp_path / "missing.mcap"),
    ]:
        with pytest.raises(FileNotFoundError) as e:
            call(path)
        err = e.value
        assert isinstance(err, vc.MissingFileError) and isinstance(err, vc.VibrocompError)
        assert err.errno == errno.ENOENT and err.filename == str(path) == err.file
        assert str(err).count("(os error 2)") == 1, str(err)
        assert str(err) == err.message and not str(err).startswith("[Errno")


def test_log_errors_name_their_file(bad, cut_log):
    for path in (bad / "notes.mcap", cut_log, bad / "folder.mcap"):
        err = raised(lambda: vc.Log(path))
        assert err.file == str(path), (path, err.to_dict())
        assert isinstance(err, vc.LogFormatError) and isinstance(err, ValueError)


def test_a_text_file_given_to_the_lab_is_not_an_mcap_log(bad):
    err = raised(lambda: vc.lab.compare(bad / "notes.mcap"))
    assert "not an MCAP log" in str(err) and "middle of a record" not in str(err), str(err)
    assert isinstance(err, vc.LogFormatError) and err.file == str(bad / "notes.mcap")


def test_hints_name_the_command_not_a_rust_function(cut_log):
    err = raised(lambda: vc.Log(cut_log))
    assert "vibro_mcap::recover" not in str(err)
    assert f"vibrocomp log recover {cut_log} OUT.mcap" in str(err), str(err)


def test_an_unknown_model_key_has_its_line_and_key(bad):
    err = raised(lambda: vc.Model.load(bad / "model-key.toml"))
    assert isinstance(err, vc.ConfigError) and isinstance(err, ValueError)
    assert (err.file, err.line, err.column, err.key) == (str(bad / "model-key.toml"), 2, 1, "bogus")


def test_an_unknown_effect_parameter_has_its_line_and_key(tmp_path):
    path = tmp_path / "model.toml"
    path.write_text('mode = "exact"\n[[effect]]\nkind = "mount_resonance"\nfreq_hz = 100.0\n'
                    'q = 5.0\nfoo = 1\n')
    err = raised(lambda: vc.Model.load(path))
    assert isinstance(err, vc.ConfigError) and err.file == str(path)
    assert (err.line, err.key) == (6, "effect[0].foo"), err.to_dict()


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_a_file_that_may_not_be_read_is_a_PermissionError(tmp_path):
    locked = tmp_path / "locked.csv"
    locked.write_text(CAMPAIGN.read_text())
    locked.chmod(0)
    with pytest.raises(PermissionError) as e:
        vc.lab.compare(locked)
    assert isinstance(e.value, vc.FilePermissionError) and e.value.file == str(locked)


# --- the hierarchy -------------------------------------------------------------------


def test_every_class_is_exported_picklable_and_a_VibrocompError():
    names = ["VibrocompError", "MissingFileError", "FilePermissionError", "FileSystemError",
             "InvalidInputError", "ConfigError", "LogFormatError"]
    bases = {"MissingFileError": FileNotFoundError, "FilePermissionError": PermissionError,
             "FileSystemError": OSError, "InvalidInputError": ValueError,
             "ConfigError": ValueError, "LogFormatError": ValueError}
    for name in names:
        cls = getattr(vc, name)
        assert cls is getattr(ve, name) and name in vc.__all__ and name in ve.__all__
        assert issubclass(cls, vc.VibrocompError) and issubclass(cls, bases.get(name, Exception))
        e = cls("f.toml: line 2: bad", ["f.toml: line 2: bad"], "f.toml", 2, 1, "a.b")
        back = pickle.loads(pickle.dumps(e))
        assert type(back) is cls and back.to_dict() == e.to_dict() and str(back) == str(e)


# --- against the command line ----------------------------------------------------------

# (name, Python call on the bad inputs' folder, the command line's arguments, class,
# the built-in exception it is too, fields both must fill: the log errors' file, which
# the command line's JSON error left out before)
CASES = [
    ("missing table", lambda d: vc.lab.compare(d / "missing.csv"),
     lambda d: ["lab", "compare", d / "missing.csv"], vc.MissingFileError, FileNotFoundError, {}),
    ("missing log in the lab", lambda d: vc.lab.compare(d / "missing.mcap"),
     lambda d: ["lab", "compare", d / "missing.mcap"], vc.MissingFileError, FileNotFoundError,
     {"file": "missing.mcap"}),
    ("missing log", lambda d: vc.Log(d / "missing.mcap"),
     lambda d: ["log", "info", d / "missing.mcap"], vc.MissingFileError, FileNotFoundError,
     {"file": "missing.mcap"}),
    ("text as a log", lambda d: vc.Log(d / "notes.mcap"),
     lambda d: ["log", "info", d / "notes.mcap"], vc.LogFormatError, ValueError,
     {"file": "notes.mcap"}),
    ("folder as a log", lambda d: vc.Log(d / "folder.mcap"),
     lambda d: ["log", "info", d / "folder.mcap"], vc.LogFormatError, ValueError,
     {"file": "folder.mcap"}),
    ("folder as a table", lambda d: vc.lab.compare(d / "folder.csv"),
     lambda d: ["lab", "compare", d / "folder.csv"], vc.FileSystemError, OSError, {}),
    ("bad table row", lambda d: vc.lab.compare(d / "row.csv"),
     lambda d: ["lab", "compare", d / "row.csv"], vc.InvalidInputError, ValueError, {}),
    ("unknown model key", lambda d: vc.Model.load(d / "model-key.toml"),
     lambda d: ["lab", "compare", CAMPAIGN, "--model", d / "model-key.toml"], vc.ConfigError,
     ValueError, {}),
    ("unknown passport key", lambda d: vc.Passport.load(d / "passport-key.toml"),
     lambda d: ["model", "ve", "--passport", d / "passport-key.toml", "--aL3-g", "1"],
     vc.ConfigError, ValueError, {}),
    ("unknown candidate", lambda d: vc.lab.diagnose(CAMPAIGN, effects=["no_such_effect"]),
     lambda d: ["lab", "diagnose", CAMPAIGN, "--effects", "no_such_effect"],
     vc.InvalidInputError, ValueError, {}),
]


CHECKED_FIRST = {"missing log in the lab"}


@pytest.mark.parametrize("name,call,args,cls,builtin,extra", CASES, ids=[c[0] for c in CASES])
def test_each_bad_input_is_the_command_lines_error_as_the_class_to_catch(
        cli, bad, name, call, args, cls, builtin, extra):
    want = cli(*args(bad), check=False)["error"]
    with pytest.raises(builtin) as e:
        call(bad)
    err = e.value
    assert type(err) is cls and isinstance(err, vc.VibrocompError), (type(err), err.to_dict())
    got = err.to_dict()
    for k in FIELDS:
        if k in extra:
            # A log's file: the command line's JSON error names it too.
            assert want.get(k) == got[k] == str(bad / extra[k]), (k, got, want)
        else:
            assert got.get(k) == want.get(k), (k, got, want)
    if name in CHECKED_FIRST:
        # The package checks a log is an MCAP log before the lab reads it (`Log()`'s
        # check), the command line does not: the same file named, another wording.
        assert str(bad / extra["file"]) in got["message"], got
        return
    # The message: the command line's (with a command's prefix the Python call has not),
    # its I/O cause not repeated.
    message, last = want["message"], ": " + want["chain"][-1]
    if message.endswith(last * 2):
        message = message[: -len(last)]
    assert message == got["message"] or message.endswith(": " + got["message"]), (got, want)
    assert got["chain"] == want["chain"] or want["chain"][1:] == got["chain"], (got, want)
