"""The scoring rules of the camera-folder benchmark (benchmarks/bench_folders.py) on hand-made
arrays: the gain, the 2 % "never hurts" rule, the lying-record rule, byte equality."""

from __future__ import annotations

import json
import math

import bench_folders as bf
import numpy as np
import pytest


def _report(cols_before, cols_after, rows=None):
    rep = {"stripes": {"columns": {"before_mm2": cols_before, "after_mm2": cols_after}}}
    rep["stripes"]["rows"] = rows
    return rep


def test_gain_is_twenty_log_of_the_rms_ratio():
    assert bf.gain_db(2.0, 1.0) == pytest.approx(20 * math.log10(2))
    assert bf.gain_db(1.0, 10.0) == pytest.approx(-20.0)
    assert bf.gain_db(3.0, 3.0) == 0.0
    assert bf.gain_db(0.0, 0.0) == 0.0
    assert bf.gain_db(1.0, 0.0) == math.inf


def test_score_frame_uses_only_pixels_valid_in_input_output_and_truth():
    true = np.zeros((2, 3))
    inp = np.array([[2.0, -2.0, 100.0], [2.0, np.nan, 2.0]])
    out = np.array([[1.0, -1.0, 0.0], [np.nan, 50.0, 1.0]])
    ok = np.array([[True, True, False], [True, True, True]])
    s = bf.score_frame(inp, out, true, ok)
    # scored: (0,0), (0,1), (1,2); (0,2) not valid in truth, (1,0) not in output, (1,1) not in input
    assert s["pixels"] == 3
    assert s["rms_in"] == pytest.approx(2.0)
    assert s["rms_out"] == pytest.approx(1.0)
    assert s["gain_db"] == pytest.approx(20 * math.log10(2))
    # a NaN truth depth is not scored either
    true2 = true.copy()
    true2[0, 0] = np.nan
    assert bf.score_frame(inp, out, true2, ok)["pixels"] == 2


def test_worse_means_more_than_two_percent_above_the_input_rms():
    assert not bf.worse(10.0, 10.19)
    assert not bf.worse(10.0, 10.2 - 1e-9)
    assert bf.worse(10.0, 10.21)
    assert not bf.worse(10.0, 5.0)


def test_claimed_reduction_is_the_best_axis_in_db():
    assert bf.claimed_reduction_db(_report(10.0, 1.0)) == pytest.approx(10.0)
    rep = _report(1.0, 1.0, {"before_mm2": 4.0, "after_mm2": 1.0})
    assert bf.claimed_reduction_db(rep) == pytest.approx(10 * math.log10(4))
    assert bf.claimed_reduction_db(_report(2.0, 4.0)) == pytest.approx(-10 * math.log10(2))
    assert bf.claimed_reduction_db(None) is None
    assert bf.claimed_reduction_db({"stripes": {"columns": None, "rows": None}}) is None


def test_a_record_lies_when_the_frame_got_worse_but_it_claims_a_reduction():
    claims = _report(2.0, 1.0)  # 3 dB down
    modest = _report(1.2, 1.0)  # 0.8 dB down
    assert bf.lying_record(10.0, 11.0, claims)
    assert not bf.lying_record(10.0, 10.1, claims)  # within 2 %
    assert not bf.lying_record(10.0, 9.0, claims)  # better
    assert not bf.lying_record(10.0, 11.0, modest)  # worse, but claims < 1 dB
    assert not bf.lying_record(10.0, 11.0, None)


def test_same_bytes(tmp_path):
    a, b, c = tmp_path / "a.png", tmp_path / "b.png", tmp_path / "c.png"
    a.write_bytes(b"\x89PNG\x00\x01")
    b.write_bytes(b"\x89PNG\x00\x01")
    c.write_bytes(b"\x89PNG\x00\x02")
    assert bf.same_bytes(a, b)
    assert not bf.same_bytes(a, c)


def test_manifest_reports_of_done_records(tmp_path):
    p = tmp_path / "manifest.jsonl"
    recs = [
        {"event": "start"},
        {"file": "f0_depth.png", "status": "failed"},
        {"file": "f1_depth.png", "status": "done", "report": _report(2.0, 1.0)},
    ]
    p.write_text("\n".join(json.dumps(r) for r in recs) + "\n")
    got = bf.read_manifest(p)
    assert list(got) == ["f1_depth.png"]
    assert got["f1_depth.png"]["stripes"]["columns"]["before_mm2"] == 2.0


def test_summary_counts_worse_frames_lies_and_byte_equality():
    base = {"family": "boxes", "seed": 0, "gain_oracle_db": 2.0}
    rows = [
        {**base, "pattern": "stripes", "stem": "a", "gain_clean_db": 2.0, "worse_clean": False},
        {
            **base,
            "pattern": "stripes",
            "stem": "b",
            "gain_clean_db": -1.0,
            "worse_clean": True,
            "lying": True,
        },
        {
            **base,
            "pattern": "none",
            "stem": "a",
            "gain_clean_db": 0.0,
            "worse_clean": False,
            "same_bytes": True,
            "gain_oracle_db": 0.0,
        },
        {
            **base,
            "pattern": "none",
            "stem": "b",
            "gain_clean_db": 0.0,
            "worse_clean": False,
            "same_bytes": False,
            "gain_oracle_db": 0.0,
        },
    ]
    s = bf.summarise(rows)
    assert s["folders"] == 2 and s["frames"] == 4
    assert s["worse_share_clean"] == pytest.approx(0.25)
    assert s["lying_records"] == ["boxes/stripes/s0/b"]
    assert s["same_bytes_share"] == pytest.approx(0.5)
    assert s["failed_frames"] == []
    # a frame the cleaner failed on: counted, left out of the clean mean and of the paired oracle
    rows.append({**base, "pattern": "stripes", "stem": "c", "gain_oracle_db": 8.0, "error": "x"})
    s = bf.summarise(rows)
    assert s["failed_frames"] == ["boxes/stripes/s0/c"]
    assert s["gain_oracle_db"] == pytest.approx(12.0 / 5)
    assert s["gain_oracle_paired_db"] == pytest.approx(1.0)
    for r in rows:
        r.update(t_make_s=1.0, t_clean_s=2.0, t_basic_s=None)
    agg = bf.aggregate(rows)
    # striped folders: clean 0.5 dB mean, oracle 2 dB; the stripe-free ones are left out
    assert agg["overall"]["gain_clean_db"] == pytest.approx(0.5)
    assert agg["overall"]["gain_oracle_db"] == pytest.approx(4.0)
    assert agg["overall"]["gain_oracle_paired_db"] == pytest.approx(2.0)
    assert agg["overall"]["clean_pct_of_oracle"] == pytest.approx(25.0)
    assert agg["by_pattern"]["none"]["gain_oracle_db"] == pytest.approx(0.0)
    assert agg["by_family"]["boxes"]["gain_clean_db"] == pytest.approx(0.25)
    assert agg["timing"]["folders"] == 2
    agg["frames"] = rows
    text = bf.table(agg)
    assert "FAILED boxes/stripes/s0: x" in text
    assert "25.0 % of oracle" in text


def test_held_out_seeds_need_the_flag_and_the_flag_only_held_out_seeds():
    with pytest.raises(SystemExit):
        bf.main(["--seeds", "1000", "--families", "boxes", "--patterns", "none"])
    with pytest.raises(SystemExit):
        bf.main(["--held-out", "--seeds", "0", "--families", "boxes", "--patterns", "none"])
    with pytest.raises(ValueError, match="held out"):
        bf.run_folder({"family": "boxes", "pattern": "none", "seed": 1000})
