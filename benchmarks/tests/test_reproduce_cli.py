"""``python benchmarks/reproduce.py``: errors (one line, exit 2, nothing written), the files it
prints, its help and its --quick size."""

from __future__ import annotations

import inspect
import os
import re

import paper as E
import pytest
import reproduce

from tof_fpn_torch.cli import _common

PREFIX = "python benchmarks/reproduce.py: error: "
RQ = ["table1", "--quick"]

BAD = [
    (["table3"], ["'table3'", "table1"]),
    (RQ + ["--threads", "0"], ["--threads", "'0'", f"[1, {_common.MAX_THREADS}]"]),
    (RQ + ["--threads", "100000"], ["--threads", "'100000'", f"[1, {_common.MAX_THREADS}]"]),
    (RQ + ["--size", "8"], ["--size", "'8'", "[32, 4096]"]),
    (RQ + ["--size", "0"], ["--size", "'0'", "[32, 4096]"]),
    (RQ + ["--size", "100000"], ["--size", "'100000'", "[32, 4096]"]),
    (RQ + ["--seeds", "-1"], ["--seeds", "'-1'", ">= 0"]),
    (RQ + ["--seeds", "1,1"], ["--seeds", "'1,1'", "distinct"]),
    (RQ + ["--seeds", "a"], ["--seeds", "'a'"]),
    (RQ + ["--h", "0"], ["--h", "'0'", ">= 1e-06"]),
    (RQ + ["--h", "1e-308"], ["--h", "'1e-308'", ">= 1e-06"]),
    (RQ + ["--patch-size", "4"], ["patch_size", "odd", "4"]),
    (RQ + ["--patch-size", "0"], ["--patch-size", "'0'", ">= 1"]),
    (RQ + ["--patch-distance", "-1"], ["--patch-distance", "'-1'", ">= 0"]),
    (RQ + ["--patch-distance", "500"], ["--patch-distance", "500", str(reproduce.QUICK_SIZE)]),
    (RQ + ["--case", "fpn"], ["--case", "fig9 only"]),
    (["fig9", "--quick", "--compensate-delay"], ["--compensate-delay", "table1 only"]),
    (RQ + ["--out", "f"], ["'f' is a file"]),
    (RQ + ["--out", "f/sub"], ["'f' is a file"]),
]


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize("argv, needles", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_argument_is_one_line_error(argv, needles, cwd, capsys):
    (cwd / "f").write_text("a file")
    assert reproduce.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(PREFIX), err
    for needle in needles:
        assert needle in err[0], (needle, err[0])
    assert sorted(p.name for p in cwd.iterdir()) == ["f"]  # nothing written


def test_reproduce_prints_the_files_it_wrote(cwd, capsys):
    argv = ["table1", "--quick", "--size", "32", "--out", "./r1/", "--no-progress"]
    assert reproduce.main(argv) == 0
    text = capsys.readouterr().out
    assert "created directory ./r1/\n" in text
    (wrote,) = re.findall(r"^wrote (.*) \(", text, flags=re.M)
    files = wrote.split(", ")
    assert files == [f"./r1/table1.{ext}" for ext in ("csv", "json", "md", "png")]
    assert all(os.path.isfile(f) for f in files)


def test_help_states_the_quick_size_it_uses(capsys, monkeypatch):
    def help_text():
        assert reproduce.main(["--help"]) == 0
        return " ".join(capsys.readouterr().out.split())

    text = help_text()
    assert f"{reproduce.QUICK_SIZE}x{reproduce.QUICK_SIZE}" in text
    assert f"--quick: {reproduce.QUICK_SIZE}" in text and not re.search(r"\b96\b", text)
    size = inspect.signature(E.run_table1).parameters["size"].default
    assert f"default {size};" in text and f"(default {E.NLMSettings.h})" in text
    monkeypatch.setattr(reproduce, "QUICK_SIZE", 77)
    assert "77x77" in help_text()


def test_quick_runs_at_the_size_the_help_states(capsys, monkeypatch):
    seen = {}

    def fake(**kwargs):
        seen.update(kwargs)
        raise ValueError("stop")

    monkeypatch.setattr(E, "run_table1", fake)
    assert reproduce.main(["table1", "--quick"]) == 2
    assert seen["size"] == reproduce.QUICK_SIZE and seen["seeds"] == reproduce.QUICK_SEEDS
