"""Table II on the raw-level simulator (benchmarks/paper/table2.py): a tiny seeded run, its
files parsed back and compared with the returned result, the paper's numbers, the CLI."""

from __future__ import annotations

import csv
import json
import re

import paper as E
import pytest
import reproduce
from paper.table2 import LABELS, TABLE2_CSV_FIELDS, table2_markdown

from tof_fpn_torch import constants as K

TINY = E.Table2Setup(size=64, frames=1, gt_frames=8)


@pytest.fixture(scope="module")
def tiny():
    return E.run_table2(TINY)


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _pair(text: str) -> tuple[float, float]:
    a, b = re.fullmatch(r"\((-?[\d.]+), (-?[\d.]+)\)", text).groups()
    return float(a), float(b)


def test_files_match_the_result(tiny, tmp_path):
    paths = E.write_table2(tiny, tmp_path)
    assert set(paths) == {"csv", "json", "md", "png"} and paths["png"].stat().st_size > 0
    methods = ["none", *E.PAPER_METHODS]
    # CSV: one row per integration time and method, numbers equal to the result's
    with open(paths["csv"]) as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == TABLE2_CSV_FIELDS
    assert len(rows) == len(K.TABLE2_INTEGRATION_TIMES) * len(methods)
    by_key = {(int(r["integration_time_us"]), r["method"]): r for r in rows}
    for j, res in enumerate(tiny["rows"]):
        it = res["integration_time_us"]
        assert it == round(K.TABLE2_INTEGRATION_TIMES[j] * 1e6)
        for m in methods:
            r = by_key[(it, m)]
            ours = res["psnr"][m]
            assert float(r["ours_not_filtered"]) == pytest.approx(ours[0], abs=1e-9)
            assert float(r["ours_filtered"]) == pytest.approx(ours[1], abs=1e-9)
            assert float(r["ours_gain"]) == pytest.approx(ours[1] - ours[0], abs=1e-9)
            paper = K.PAPER_TABLE2[m][j]
            assert (float(r["paper_not_filtered"]), float(r["paper_filtered"])) == paper
            assert float(r["low"]) == pytest.approx(res["low"], abs=1e-9)
            assert (float(r["paper_low"]), float(r["paper_imp"])) == K.PAPER_TABLE2_SENSING[j]
    # JSON: the result without the images
    data = json.loads(paths["json"].read_text())
    assert "_images" not in data and data["rows"] == json.loads(json.dumps(tiny["rows"]))
    assert data["setup"]["gt_frames"] == TINY.gt_frames
    # Markdown: the first table's cells are the result rounded to 0.1 dB, beside the paper's
    md = paths["md"].read_text()
    assert md == table2_markdown(tiny)
    lines = md.splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("| IT |"))
    header = _cells(lines[head])
    for j, res in enumerate(tiny["rows"]):
        cells = _cells(lines[head + 2 + j])
        assert cells[0] == f"{res['integration_time_us']} us"
        low, imp = map(float, re.fullmatch(r"\{(\d+), (\d+)\}", cells[1]).groups())
        assert low == pytest.approx(res["low"], abs=0.5) and imp == pytest.approx(
            res["imp"], abs=0.5
        )
        for m in methods:
            col = header.index(f"{LABELS[m]} ours")
            ours = _pair(cells[col])
            assert ours == pytest.approx(tuple(res["psnr"][m]), abs=0.051), (m, j)
            assert _pair(cells[col + 1]) == K.PAPER_TABLE2[m][j]


def test_each_denoiser_improves_and_gains_from_fpn_suppression_at_50us(tiny):
    r = tiny["rows"][0]
    assert r["integration_time_us"] == round(K.TABLE2_INTEGRATION_TIMES[0] * 1e6)
    base = r["psnr"]["none"]
    assert base[1] > base[0]  # the FPN stage alone helps
    for m in E.PAPER_METHODS:
        o = r["psnr"][m]
        assert o[0] > base[0] and o[1] > base[1], m  # better than its input
        assert o[1] > o[0] + 1.0, m  # FPN suppression helps every denoiser
    # more light, better data: PSNR of the input and the low-sensing share are monotone
    assert [x["psnr"]["none"][0] for x in tiny["rows"]] == sorted(
        x["psnr"]["none"][0] for x in tiny["rows"]
    )
    assert [x["low"] for x in tiny["rows"]] == sorted(
        (x["low"] for x in tiny["rows"]), reverse=True
    )
    assert "NO" not in table2_markdown(tiny).split("## Checks")[1]


def test_noise_from_the_unfiltered_frame():
    """``noise="input"``: k from the unfiltered frame for both columns; the unfiltered column is
    what a denoiser built with that k gives, and the Markdown says which rule was used."""
    setup = E.Table2Setup(size=48, frames=2, gt_frames=4)
    r = E.run_table2(setup, methods=("lpa-ici", "joint-bilateral"), noise="input")
    own = E.run_table2(setup, methods=("lpa-ici", "joint-bilateral"))
    assert r["noise"] == "input" and "on the unfiltered frame" in table2_markdown(r)
    assert "by each denoiser on its input" in table2_markdown(own)
    for a, b in zip(r["rows"], own["rows"], strict=True):
        assert a["psnr"]["none"] == b["psnr"]["none"]
        assert a["psnr"]["joint-bilateral"] == b["psnr"]["joint-bilateral"]  # takes no k
        # the same k on the unfiltered frames (estimated there either way): same numbers
        assert a["psnr"]["lpa-ici"][0] == pytest.approx(b["psnr"]["lpa-ici"][0], abs=1e-4)
    assert any(
        abs(a["psnr"]["lpa-ici"][1] - b["psnr"]["lpa-ici"][1]) > 1e-3
        for a, b in zip(r["rows"], own["rows"], strict=True)
    )
    with pytest.raises(ValueError, match="noise must be"):
        E.run_table2(setup, noise="filtered")


def test_bad_settings_and_names():
    with pytest.raises(ValueError, match="size"):
        E.Table2Setup(size=8).validate()
    with pytest.raises(ValueError, match="frames"):
        E.Table2Setup(frames=0).validate()
    with pytest.raises(ValueError, match="unknown denoiser"):
        E.run_table2(TINY, methods=("nlm", "wiener"))


def test_cli_reproduce_table2(tmp_path, capsys):
    out = tmp_path / "t2"
    main = reproduce.main
    argv = ["table2", "--size", "48", "--frames", "1", "--gt-frames", "4"]
    assert main([*argv, "--out", str(out), "--no-progress"]) == 0
    data = json.loads((out / "table2.json").read_text())
    assert data["setup"]["size"] == 48 and data["setup"]["gt_frames"] == 4
    assert "50 us: LOW" in capsys.readouterr().out
    assert main([*argv, "--seeds", "1", "--out", str(tmp_path / "x")]) == 2
    assert "--seeds does not apply to table2" in capsys.readouterr().err
    assert main(["table1", "--frames", "2", "--out", str(tmp_path / "y")]) == 2
    assert main([*argv, "--denoisers", "wiener", "--out", str(tmp_path / "z")]) == 2
    assert "unknown denoiser 'wiener'" in capsys.readouterr().err
    out2 = tmp_path / "t2b"
    assert (
        main([*argv, "--denoisers", "Guided,sliding_dct", "--out", str(out2), "--no-progress"]) == 0
    )
    data = json.loads((out2 / "table2.json").read_text())
    assert data["methods"] == ["guided", "sdct"]
    assert set(data["rows"][0]["psnr"]) == {"none", "guided", "sdct"}
    md = (out2 / "table2.md").read_text()
    assert "| Guided ours | paper | sDCT ours | paper |" in md
    # no paper value for the guided filter: one "-" per integration time in both tables
    assert "(24.4, 26.4) |" in md and md.count(" - |") == 2 * len(K.TABLE2_INTEGRATION_TIMES)
