"""Edge cases of ``tof-fpn clean`` / ``convert`` / ``diagnose``: frames one pixel wide, stages that
invalidate pixels, folders where nothing can be read, a missing optional extra, and a summary that
tells one story when the stage did nothing."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from _clean_data import frame, png_folder
from PIL import Image

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean.measure import finite_values, summarise
from tof_fpn_torch.clean.work import THIN_NOTE
from tof_fpn_torch.cli import main

MKV_HINT = 'pip install "tof_fpn_torch[mkv]"'


def _strict(text: str) -> list[dict]:
    """The manifest's lines, parsed as strict JSON (a bare NaN / Infinity is an error)."""

    def refuse(name):
        raise ValueError(f"not JSON: {name}")

    return [json.loads(line, parse_constant=refuse) for line in text.splitlines()]


def _records(out: Path) -> dict[str, dict]:
    return {r["file"]: r for r in _strict((out / "manifest.jsonl").read_text()) if "file" in r}


def _pair(folder: Path, name: str, h: int, w: int, seed: int = 1) -> None:
    d, a = frame(np.random.default_rng(seed), h, w)
    tio.write_pair(folder / f"{name}_depth.png", d, a, folder / f"{name}_amplitude.png")


def _eight_bit(folder: Path, name: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((20, 20), 100, np.uint8)).save(folder / f"{name}_depth.png")
    Image.fromarray(np.full((20, 20), 90, np.uint8)).save(folder / f"{name}_amplitude.png")


def _mismatched(folder: Path, name: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((20, 20), 1000, np.uint16)).save(folder / f"{name}_depth.png")
    Image.fromarray(np.full((20, 24), 90, np.uint16)).save(folder / f"{name}_amplitude.png")


# --- 1. frames one pixel wide or high --------------------------------------------------------


@pytest.mark.parametrize("size", [(1, 1), (1, 80), (80, 1)])
def test_a_one_pixel_wide_frame_is_copied_with_a_note_and_the_run_goes_on(tmp_path, capsys, size):
    src, out = tmp_path / "in", tmp_path / "out"
    png_folder(src, 3, sub_every=0)  # f000..f002: striped 32 x 40 frames
    _pair(src, "a", *size)  # first in file order: the calibration must pass over it
    _eight_bit(src, "bad")  # a file that fails: its reason must still be printed
    status = main(["clean", str(src), str(out), "--quiet", "--no-figure"])
    std = capsys.readouterr()
    assert status == 1, std
    assert "Traceback" not in std.err and len(std.err.strip().splitlines()) == 1
    assert "failed: bad_depth.png:" in std.out and "8-bit" in std.out
    for kind in ("depth", "amplitude"):  # copied as it came, byte for byte
        name = f"a_{kind}.png"
        assert (out / name).read_bytes() == (src / name).read_bytes()
    recs = _records(out)
    thin = recs["a_depth.png"]
    assert thin["status"] == "done" and thin["note"] == THIN_NOTE
    assert "error" not in thin["report"] and thin["report"]["changed"] == 0
    # nothing to measure a stripe on: null, not NaN nor a made-up 0
    assert thin["report"]["stripes"]["columns"] == dict.fromkeys(("before_mm2", "after_mm2", "z"))
    assert thin["report"]["stripes"]["rows"] == thin["report"]["stripes"]["columns"]
    assert thin["report"]["noise_mm"] is None and not thin["report"]["found"]
    assert "copied 1 file(s) with frames one pixel wide or high" in std.out
    # the striped files were cleaned as usual
    assert all(recs[f"f00{i}_depth.png"]["report"]["changed"] > 0 for i in range(3))
    assert "changed 3 of 4 file(s)" in std.out


def test_only_one_pixel_wide_frames_name_the_reason(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    _pair(src, "a", 1, 80)
    status = main(["clean", str(src), str(tmp_path / "out"), "--quiet", "--no-figure"])
    std = capsys.readouterr()
    assert status == 2 and "failed: a_depth.png: 1x80 frames, one pixel wide" in std.out
    assert std.err.strip().splitlines() == [
        "tof-fpn clean: error: no readable frame with a valid pixel in INPUT (1 file(s), each "
        "with its reason above)"
    ]
    # nothing measured on data: the frame is copied as it came, with the note
    assert main(["clean", str(src), str(tmp_path / "o2"), "--quiet", "--stage", "paper"]) == 0
    assert (tmp_path / "o2" / "a_depth.png").read_bytes() == (src / "a_depth.png").read_bytes()
    assert _records(tmp_path / "o2")["a_depth.png"]["note"] == THIN_NOTE


# --- 2. no NaN in the summary or the manifest -------------------------------------------------


def test_flying_invalidate_prints_and_records_no_nan(tmp_path, capsys):
    src = png_folder(tmp_path / "in", 3, sub_every=0)
    assert main(["clean", str(src), str(tmp_path / "plain"), "--quiet", "--no-figure"]) == 0
    capsys.readouterr()
    out = tmp_path / "out"
    assert (
        main(["clean", str(src), str(out), "--quiet", "--no-figure", "--flying", "invalidate"]) == 0
    )
    text = capsys.readouterr().out
    assert "nan" not in text.lower() and "inf " not in text.lower()
    recs, plain = _records(out), _records(tmp_path / "plain")
    assert "NaN" not in (out / "manifest.jsonl").read_text()
    flagged = sum(r["report"]["flying"]["flagged"] for r in recs.values())
    assert flagged > 0  # pixels were invalidated: the case where the measure went NaN
    for name, rec in recs.items():
        moved = rec["report"]["lowpass_change_mm"]
        # on the pixels valid in both: the scene moved as little as without the flying stage
        assert math.isfinite(moved) and moved > 0
        assert moved == pytest.approx(plain[name]["report"]["lowpass_change_mm"], abs=0.2)
    line = next(x for x in text.splitlines() if x.startswith("low-pass depth moved at most"))
    assert float(line.split()[5]) == pytest.approx(
        max(r["report"]["lowpass_change_mm"] for r in recs.values()), abs=0.006
    )


def test_finite_values_turns_every_undefined_number_into_null():
    rec = {"a": math.nan, "b": [1.0, math.inf, {"c": -math.inf}], "d": 2, "e": "nan", "f": None}
    assert finite_values(rec) == {"a": None, "b": [1.0, None, {"c": None}], "d": 2, "e": "nan",
                                  "f": None}  # fmt: skip
    json.dumps(finite_values(rec), allow_nan=False)


# --- 3. every file's reason when nothing could be read ---------------------------------------


@pytest.mark.parametrize(
    ("makers", "words"),
    [
        ((_eight_bit,), ["8-bit depth"]),
        ((_mismatched,), ["must have the same shape"]),
        ((_eight_bit, _mismatched), ["8-bit depth", "must have the same shape"]),
    ],
)
def test_a_folder_where_nothing_can_be_read_prints_every_reason(tmp_path, capsys, makers, words):
    src = tmp_path / "in"
    for i, make in enumerate(makers):
        make(src, f"x{i}")
    status = main(["clean", str(src), str(tmp_path / "out"), "--quiet"])
    std = capsys.readouterr()
    assert status == 2 and not (tmp_path / "out").exists()  # refused before anything is written
    failed = [x for x in std.out.splitlines() if x.startswith("failed: ")]
    assert len(failed) == len(makers)
    for i, (line, word) in enumerate(zip(failed, words, strict=True)):
        assert line.startswith(f"failed: x{i}_depth.png: ") and word in line
    err = std.err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tof-fpn clean: error: no readable frame")
    assert f"({len(makers)} file(s), each with its reason above)" in err[0]


# --- 4. a missing optional extra: one line naming it ------------------------------------------


def _no_pyav(tmp_path, monkeypatch) -> Path:
    src = tmp_path / "in"
    src.mkdir()
    (src / "take.mkv").write_bytes(b"not read: the reader stops before")
    monkeypatch.setitem(sys.modules, "av", None)  # import av -> ImportError
    return src


def test_clean_without_pyav_names_the_extra(tmp_path, monkeypatch, capsys):
    src = _no_pyav(tmp_path, monkeypatch)
    # the default stage measures on the data: no frame to measure on, the reason names the extra
    assert main(["clean", str(src), str(tmp_path / "a"), "--quiet"]) == 2
    std = capsys.readouterr()
    (line,) = [x for x in std.out.splitlines() if x.startswith("failed:")]
    assert line.startswith("failed: take.mkv: Azure Kinect") and line.endswith(MKV_HINT)
    assert "MissingExtraError" not in line and "Traceback" not in std.err
    assert len(std.err.strip().splitlines()) == 1
    # nothing measured: the file fails in the run, one line naming the extra
    assert main(["clean", str(src), str(tmp_path / "b"), "--quiet", "--stage", "paper"]) == 1
    std = capsys.readouterr()
    (line,) = [x for x in std.out.splitlines() if x.startswith("failed:")]
    assert line.startswith("failed: take.mkv: Azure Kinect") and line.endswith(MKV_HINT)
    assert "MissingExtraError" not in line
    rec = _records(tmp_path / "b")["take.mkv"]
    assert rec["status"] == "failed" and rec["error"].endswith(MKV_HINT)


def test_convert_without_pyav_names_the_extra_in_one_line(tmp_path, monkeypatch, capsys):
    src = _no_pyav(tmp_path, monkeypatch)
    assert main(["convert", str(src), str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tof-fpn convert: error: take.mkv: ")
    assert err[0].endswith(MKV_HINT)


def test_diagnose_without_pyav_names_the_extra_in_one_line(tmp_path, monkeypatch, capsys):
    src = _no_pyav(tmp_path, monkeypatch)
    status = main(["diagnose", str(src / "take.mkv"), "--out", str(tmp_path / "d")])
    std = capsys.readouterr()
    err = std.err.strip().splitlines()
    assert status == 2 and len(err) == 1, std
    assert err[0].startswith("tof-fpn diagnose: error: Azure Kinect") and err[0].endswith(MKV_HINT)
    assert not (tmp_path / "d").exists()


# --- 5. one story when the stage did nothing --------------------------------------------------


def test_a_stage_that_did_nothing_and_a_pattern_the_record_sees_tell_one_story(tmp_path, capsys):
    """Measured on a stripe-free first frame, the stage has nothing to do; the later files have
    stripes. The summary must not say both "nothing found" and "stripes found"."""
    src = tmp_path / "in"
    src.mkdir()
    rng = np.random.default_rng(1)
    flat = (1.0 + 0.002 * rng.standard_normal((64, 80))).astype(np.float32)
    tio.write_pair(src / "a_depth.png", flat, np.full((64, 80), 90.0), src / "a_amplitude.png")
    for name in "bcd":
        d, a = frame(rng, 64, 80)
        tio.write_pair(src / f"{name}_depth.png", d, a, src / f"{name}_amplitude.png")
    out = tmp_path / "out"
    args = ["clean", str(src), str(out), "--quiet", "--no-figure", "--calibration-frames", "1"]
    assert main(args) == 0
    lines = capsys.readouterr().out.splitlines()
    text = "\n".join(lines)
    recs = _records(out)
    found = sum(r["report"]["found"] for r in recs.values())
    assert found == 3 and not any(r["report"]["changed"] for r in recs.values())
    assert "nothing to do" in lines[1] and "stripes or broadband offsets found" not in lines[1]
    assert "stripes found in" not in text and "stripe energy down" not in text
    assert "changed 0 of 4 file(s)" in lines
    assert (
        "the stage found nothing it could remove with confidence; the record's stripe measure "
        "sees a pattern in 3 file(s) (common to both halves of the frame, z >= 4): left as they "
        "were"
    ) in lines
    assert "did not act" not in text


def _rep(found: bool, changed: float) -> dict:
    stripes = {"before_mm2": 100.0 if found else 0.0, "after_mm2": 1.0, "z": 9.0 if found else 0}
    return {
        "status": "done",
        "report": {
            "found": found,
            "changed": changed,
            "noise_mm": 1.0,
            "lowpass_change_mm": 0.1,
            "stripes": {"columns": stripes, "rows": dict(stripes, z=0.0)},
        },
    }


def test_the_summary_says_which_striped_files_were_left_as_they_were():
    lines = summarise([_rep(True, 0.5), _rep(True, 0.0), _rep(False, 0.0)])
    assert lines[0].startswith("changed 1 of 3 file(s); stripes found in 2")
    assert lines[1] == (
        "1 of them left as they were: the stage found nothing there it could remove with confidence"
    )
    assert "median over 1 file(s)" in lines[2]  # only the file the stage acted on
    off = summarise([_rep(True, 0.0)], stages_off=True)
    assert off[1].startswith("every stage is off; the record's stripe measure sees a pattern in 1")
    assert "nothing was changed: the outputs hold the input depth" in off
    none = summarise([_rep(False, 0.0)])
    assert none[0].startswith("changed 0 of 1 file(s); stripes found in 0")
    assert none[-1] == "nothing was changed: the outputs hold the input depth (no stripe found)"


def test_a_record_that_could_not_be_measured_does_not_break_the_summary():
    lines = summarise([{"status": "done", "report": {"error": "not measured: x"}}, _rep(True, 1.0)])
    assert lines[0].startswith("1 file(s) written but not measured")
    assert lines[1].startswith("changed 1 of 1 file(s); stripes found in 1")
