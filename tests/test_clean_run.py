"""``tof-fpn clean`` end to end on the local engine: outputs, resume, refusals, bad input."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from _clean_data import png_folder, tree

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import CleanConfig, build_pipeline, clean
from tof_fpn_torch.clean import work as clean_work
from tof_fpn_torch.clean.manifest import read_manifest
from tof_fpn_torch.cli import main


def _done_counts(out) -> dict[str, int]:
    counts: dict[str, int] = {}
    for rec in read_manifest(os.path.join(out, "manifest.jsonl")):
        if rec.get("status") == "done":
            counts[rec["file"]] = counts.get(rec["file"], 0) + 1
    return counts


def _cli(argv, capsys):
    status = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return status, cap.out, cap.err.strip().splitlines()


def test_output_keeps_names_dtypes_units_and_invalid_pixels(tmp_path, capsys):
    src = png_folder(tmp_path / "in", 10)
    out = tmp_path / "out"
    status, stdout, err = _cli(["clean", src, out, "--quiet"], capsys)
    assert status == 0 and err == [], err
    assert stdout.startswith(f"created directory {out}\nstage auto, measured on 8 calibration")
    assert "\ncleaned 10 file(s) (10 frames)" in stdout and f"figure: {out}/report.png" in stdout
    inputs = tree(src)
    outputs = tree(out, skip=("manifest.jsonl", "clean.toml", "report.png"))
    assert sorted(outputs) == sorted(inputs)  # the same names, sub-folders included
    stripes_in = stripes_out = 0.0
    for name, data in inputs.items():
        if "_amplitude" in name:
            assert outputs[name] == data  # amplitude untouched, byte for byte
            continue
        d_in = tio.read_png(src / name, allow_empty=True)[0, 0].numpy()
        raw_in = np.asarray(__import__("PIL.Image").Image.open(src / name))
        raw_out = np.asarray(__import__("PIL.Image").Image.open(out / name))
        assert raw_out.dtype == raw_in.dtype == np.uint16 and raw_out.shape == raw_in.shape
        assert np.array_equal(raw_out == 0, raw_in == 0)  # invalid stays invalid, valid valid
        d_out = raw_out * 1e-3
        x = np.arange(d_in.shape[1])
        for d, acc in ((d_in, "in"), (d_out, "out")):
            profile = np.nanmean(np.where(raw_in > 0, d, np.nan), axis=0)
            e = abs(np.mean((profile - profile.mean()) * np.cos(np.pi * x)))
            if acc == "in":
                stripes_in += e
            else:
                stripes_out += e
    assert stripes_out < 0.2 * stripes_in  # the stripes at pi are gone
    assert (out / "clean.toml").read_text().startswith('[tof_fpn_torch]\nversion = "')
    assert set(_done_counts(out).values()) == {1} and len(_done_counts(out)) == 10


def test_worker_modes_give_the_same_bytes(tmp_path):
    src = png_folder(tmp_path / "in", 21, sub_every=4)
    cfg = CleanConfig(destripe="columns", batch=4)
    trees = []
    for i, kw in enumerate(
        [{"workers": 0}, {"workers": 2}, {"workers": 2, "compute_in_workers": False}]
    ):
        rep = clean(str(src), str(tmp_path / f"o{i}"), cfg, device="cpu", **kw)
        assert rep.status == 0 and rep.done == 21
        trees.append(tree(tmp_path / f"o{i}"))
    assert trees[0] == trees[1] == trees[2]


@pytest.mark.slow
def test_resume_skips_finished_and_redoes_missing_or_changed(tmp_path):
    src = png_folder(tmp_path / "in", 12, sub_every=0)
    cfg = CleanConfig(destripe="columns", batch=4)
    ref = clean(str(src), str(tmp_path / "ref"), cfg)
    assert ref.done == 12
    out = tmp_path / "out"
    clean(str(src), str(out), cfg)
    for name in ("f001_depth.png", "f006_depth.png"):  # two groups only partly finished
        os.remove(out / name)
    os.utime(src / "f010_amplitude.png", ns=(time.time_ns(), time.time_ns()))  # input changed
    again = clean(str(src), str(out), cfg)
    assert (again.done, again.already_done) == (3, 9)
    assert tree(out) == tree(tmp_path / "ref")
    last = clean(str(src), str(out), cfg)
    assert (last.done, last.already_done) == (0, 12)


def test_hdf5_file_input_keeps_structure_and_values(tmp_path):
    rng = np.random.default_rng(3)
    src = tmp_path / "recording.h5"
    frames = [np.stack([f for f, _ in (png_frame(rng) for _ in range(5))]) for _ in range(2)]
    with h5py.File(src, "w") as f:
        f.attrs["camera"] = "test"
        for i, d in enumerate(frames):
            g = f.create_group(f"take{i}")
            g.create_dataset(
                "depth", data=np.where(np.isfinite(d), np.rint(d * 1000), 0).astype(np.uint16)
            )
            g.create_dataset("amplitude", data=np.full(d.shape, 100, np.uint16))
    out = tmp_path / "out"
    config = CleanConfig(stage="paper", batch=3, rounding="nearest")
    rep = clean(str(src), str(out), config)
    assert rep.status == 0 and rep.frames == 10
    pipe = build_pipeline(config)
    with h5py.File(src) as a, h5py.File(out / "recording.h5") as b:
        assert b.attrs["camera"] == "test" and sorted(b) == ["take0", "take1"]
        for key in ("take0", "take1"):
            d_in = a[f"{key}/depth"][()]
            assert b[f"{key}/depth"].dtype == np.uint16 and b[f"{key}/depth"].shape == d_in.shape
            assert np.array_equal(b[f"{key}/amplitude"][()], a[f"{key}/amplitude"][()])
            assert np.array_equal(b[f"{key}/depth"][()] == 0, d_in == 0)
            depth = tio.read_hdf5(src, depth_key=f"{key}/depth", amplitude_key=f"{key}/amplitude")
            expect, _ = pipe(*depth)  # the first three frames were one batch, as here
            got = b[f"{key}/depth"][()].astype(np.float64) * 1e-3
            valid = d_in > 0
            assert np.abs(got - expect[:, 0].double().numpy())[valid].max() <= 0.5e-3 + 1e-9


def png_frame(rng):
    from _clean_data import frame

    return frame(rng)


@pytest.mark.parametrize(
    "make, needle",
    [
        (lambda p: [p / "in"], "is INPUT itself"),
        (lambda p: [p / "in", p / "in" / "sub" / "out"], "inside INPUT"),
        (lambda p: [p / "in" / "f000_depth.png", p / "in"], "directory of INPUT"),
        (lambda p: [p / "missing", p / "o"], "does not exist"),
        (lambda p: [p / "foreign"], "not empty and holds no manifest.jsonl"),
        (lambda p: [p / "afile"], "is a file"),
    ],
)
def test_refusals_are_one_line_and_write_nothing(tmp_path, capsys, make, needle):
    png_folder(tmp_path / "in", 3)
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "keep.txt").write_text("mine")
    (tmp_path / "afile").write_text("x")
    paths = make(tmp_path)
    argv = ["clean", tmp_path / "in", *paths] if len(paths) == 1 else ["clean", *paths]
    before = tree(tmp_path, skip=())
    status, out, err = _cli(argv, capsys)
    assert status == 2 and len(err) == 1 and err[0].startswith("tof-fpn clean: error: "), err
    assert needle in err[0]
    assert tree(tmp_path, skip=()) == before


def test_another_config_into_the_same_output_is_refused(tmp_path, capsys):
    png_folder(tmp_path / "in", 3)
    assert _cli(["clean", tmp_path / "in", tmp_path / "o", "--quiet"], capsys)[0] == 0
    status, _, err = _cli(["clean", tmp_path / "in", tmp_path / "o", "--order", "30"], capsys)
    assert status == 2 and "another configuration" in err[0] and len(err) == 1


def _bad_inputs(root):
    png_folder(root, 6, sub_every=0)
    (root / "corrupt_depth.png").write_bytes(b"\x89PNG\r\n\x1a\nnot really")
    (root / "corrupt_amplitude.png").write_bytes((root / "f000_amplitude.png").read_bytes())
    data = (root / "f001_depth.png").read_bytes()
    (root / "trunc_depth.png").write_bytes(data[: len(data) // 2])
    (root / "trunc_amplitude.png").write_bytes((root / "f001_amplitude.png").read_bytes())
    tio.write_png(root / "shape_depth.png", np.full((32, 40), 2.0, np.float32))
    tio.write_png(root / "shape_amplitude.png", np.full((30, 40), 9.0, np.float32), "amplitude")
    tio.write_png(root / "nan_depth.png", np.full((32, 40), np.nan, np.float32))
    tio.write_png(root / "nan_amplitude.png", np.full((32, 40), 9.0, np.float32), "amplitude")
    tio.write_png(root / "lonely_depth.png", np.full((32, 40), 2.0, np.float32))
    with h5py.File(root / "strings.h5", "w") as f:
        f.create_dataset("depth", data=np.array([b"a", b"b"]))
        f.create_dataset("amplitude", data=np.zeros(2))
    (root / "locked").mkdir()
    png_folder(root / "locked", 1)
    return {
        "corrupt_depth.png": "cannot read",
        "trunc_depth.png": "cannot read",
        "shape_depth.png": "same shape",
        "lonely_depth.png": "no partner",
        "strings.h5": "dtype",
        "locked/": "cannot read directory",
    }


def test_bad_input_is_listed_with_its_reason_and_the_rest_is_done(tmp_path, capsys, monkeypatch):
    expected = _bad_inputs(tmp_path / "in")
    real_scandir = os.scandir

    def scandir(path="."):  # root reads any directory: refuse this one as a chmod 000 would
        if os.fspath(path).endswith("locked"):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        return real_scandir(path)

    monkeypatch.setattr(os, "scandir", scandir)
    out = tmp_path / "out"
    status, stdout, err = _cli(["clean", tmp_path / "in", out, "--quiet", "--workers", "2"], capsys)
    assert status == 1
    assert err == [
        f"tof-fpn clean: error: 6 of 13 file(s) failed (reasons above and in {out}/manifest.jsonl)"
    ]
    for name, needle in expected.items():  # each failure on a line of its own, with its reason
        assert any(
            line.startswith(f"failed: {name}: ") and needle in line for line in stdout.splitlines()
        )
    records = [r for r in read_manifest(str(out / "manifest.jsonl")) if "file" in r]
    failed = {r["file"]: r["error"] for r in records if r["status"] == "failed"}
    assert sorted(failed) == sorted(expected)
    for name, needle in expected.items():
        assert needle in failed[name], (name, failed[name])
    # a frame with no valid pixel has nothing to clean: it is written as it came
    assert sorted(_done_counts(out)) == sorted(
        ["nan_depth.png"] + [f"f{i:03d}_depth.png" for i in range(6)]
    )
    done = {r["file"]: r for r in records if r["status"] == "done"}
    assert done["nan_depth.png"]["empty_frames"] == 1
    assert (out / "nan_depth.png").read_bytes() == (tmp_path / "in" / "nan_depth.png").read_bytes()
    names = set(tree(out, skip=("manifest.jsonl", "clean.toml", "report.png")))
    pngs = {f"f{i:03d}_{k}.png" for i in range(6) for k in ("depth", "amplitude")}
    assert names == pngs | {"nan_depth.png", "nan_amplitude.png"}


def test_a_failed_write_leaves_nothing_under_the_output_name(tmp_path, monkeypatch):
    png_folder(tmp_path / "in", 4, sub_every=0)
    real = clean_work.write_like

    def half_then_fail(src, dst, *args):
        if "f002" in str(src):
            open(dst, "wb").write(b"half")
            raise OSError(28, "No space left on device")
        return real(src, dst, *args)

    monkeypatch.setattr(clean_work, "write_like", half_then_fail)
    rep = clean(str(tmp_path / "in"), str(tmp_path / "out"))
    assert (rep.done, rep.failed, rep.status) == (3, 1, 1)
    assert "No space left on device" in rep.failures[0][1]
    files = {p.name for p in (tmp_path / "out").iterdir()}
    assert not any(n.startswith("f002") or n.endswith(".tmp") for n in files), files


def test_manifest_records_status_timing_and_inputs(tmp_path):
    png_folder(tmp_path / "in", 3, sub_every=0)
    cfg = CleanConfig(denoise="nlm", denoise_options={"patch_distance": 3})
    clean(str(tmp_path / "in"), str(tmp_path / "out"), cfg)
    lines = (tmp_path / "out" / "manifest.jsonl").read_text().splitlines()
    start, *files, end = (json.loads(s) for s in lines)
    assert start["event"] == "start" and start["pipeline"]["denoise"].startswith("NonLocalMeans")
    assert end["event"] == "end" and (end["done"], end["failed"], end["interrupted"]) == (
        3,
        0,
        None,
    )
    for rec in files:
        assert rec["status"] == "done" and rec["frames"] == 1 and rec["compute_s"] > 0
        assert rec["outputs"] == [rec["file"], rec["file"].replace("_depth", "_amplitude")]
        assert len(rec["input"]["size"]) == 2 and rec["read_s"] >= 0 and rec["write_s"] > 0
    assert torch.get_num_threads() >= 1


def test_readme_clean_command_works_as_written(tmp_path, capsys, monkeypatch):
    import re
    import shlex

    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = re.search(r"<!-- clean-command -->\s*```bash\n(.*?)```", text, re.S)
    assert block, "README has no <!-- clean-command --> block"
    words = shlex.split(block.group(1).strip())
    assert words[:2] == ["tof-fpn", "clean"] and len(block.group(1).strip().splitlines()) == 1
    monkeypatch.chdir(tmp_path)
    png_folder(tmp_path / words[2], 3)
    status, out, err = _cli([*words[1:], "--quiet"], capsys)
    assert status == 0, err
    assert (
        f"created directory {words[3]}" in out
        and (tmp_path / words[3] / "manifest.jsonl").is_file()
    )


def test_progress_bar_shows_rate_and_eta(tmp_path, capsys):
    png_folder(tmp_path / "in", 3, sub_every=0)
    clean(str(tmp_path / "in"), str(tmp_path / "out"), progress=True)
    err = capsys.readouterr().err
    assert "clean: 100%" in err and "3/3" in err and "file/s" in err and "<00:00" in err


def test_a_single_file_input_finds_its_partner(tmp_path):
    png_folder(tmp_path / "in", 2, sub_every=0)
    rep = clean(str(tmp_path / "in" / "f001_amplitude.png"), str(tmp_path / "out"))
    assert (rep.done, rep.jobs) == (1, 1)
    assert {p.name for p in (tmp_path / "out").glob("*.png")} == {
        "f001_depth.png",
        "f001_amplitude.png",
        "report.png",
    }


def test_a_run_stopped_before_its_manifest_resumes(tmp_path):
    png_folder(tmp_path / "in", 2, sub_every=0)
    clean(str(tmp_path / "in"), str(tmp_path / "ref"))
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "clean.toml").write_bytes((tmp_path / "ref" / "clean.toml").read_bytes())
    rep = clean(str(tmp_path / "in"), str(tmp_path / "out"))
    assert rep.done == 2 and tree(tmp_path / "out") == tree(tmp_path / "ref")
