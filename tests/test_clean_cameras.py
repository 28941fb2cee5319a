"""``tof-fpn clean`` on a folder that mixes cameras: the files are grouped by camera
(:func:`~tof_fpn_torch.clean.cameras.camera_groups`, from headers only) and each group is
measured and cleaned on its own, so every file comes out as it would from its camera's files alone
(the real ADI and Azure Kinect captures; two synthetic cameras, one striped, one clean), on both
engines, resumed too."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from _clean_data import frame, tree
from conftest import real_capture
from PIL import Image

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import CleanConfig, clean
from tof_fpn_torch.clean.cameras import UNKNOWN_SIZE, UNMEASURED, camera_groups, camera_key
from tof_fpn_torch.clean.manifest import read_manifest
from tof_fpn_torch.clean.plan import plan_jobs
from tof_fpn_torch.clean.work import NoFramesError
from tof_fpn_torch.cli import main
from tof_fpn_torch.io.headers import frame_sizes
from tof_fpn_torch.sim import add_depth_noise, synthetic_scene

OFFICE = "adi_adtf3175/office_mode3_interleaved_512x512.bin"
MKV = "azure_kinect/desk_recording.mkv"


def _records(out: Path) -> dict[str, dict]:
    return {r["file"]: r for r in read_manifest(str(out / "manifest.jsonl")) if "file" in r}


def _start(out: Path) -> dict:
    return next(r for r in read_manifest(str(out / "manifest.jsonl")) if r.get("event") == "start")


def _png_pair(folder: Path, name: str, depth_mm: np.ndarray, amplitude: np.ndarray) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(depth_mm.astype(np.uint16)).save(folder / f"{name}_depth.png")
    Image.fromarray(amplitude.astype(np.uint16)).save(folder / f"{name}_amplitude.png")


# --- the groups ---------------------------------------------------------------------------------


def test_camera_groups_by_format_and_size_from_headers_only(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    rng = np.random.default_rng(0)
    small, large = frame(rng, 12, 16), frame(rng, 20, 24)
    # PNG pairs of two sizes, their names interleaved
    for name, (d, a) in (("a", small), ("b", large), ("c", small), ("d", large)):
        tio.write_pair(src / f"{name}_depth.png", d, a, src / f"{name}_amplitude.png")
    tio.write_tiff(src / "e_depth.tif", small[0], "depth")
    tio.write_tiff(src / "e_amplitude.tif", small[1], "amplitude")
    tio.write_npy(src / "f_depth.npy", large[0], "depth")
    tio.write_npy(src / "f_amplitude.npy", large[1], "amplitude")
    tio.write_npz(src / "g.npz", np.stack([small[0]] * 3), np.stack([small[1]] * 3))
    tio.write_hdf5(src / "h.h5", large[0], large[1])
    tio.write_raw(src / "i_depth.bin", small[0], "depth")
    tio.write_raw(src / "i_amplitude.bin", small[1], "amplitude")
    for name in ("j_depth_u16le_6x8.bin", "j_ir_u16le_6x8.bin"):  # an ADI pair: size by name
        np.zeros((6, 8), "<u2").tofile(src / name)
    for rec in ("m1.mkv", "m2.mkv"):  # containers: each its own camera (not read here)
        (src / rec).write_bytes(b"not a recording")
    (src / "n_depth.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")  # header unreadable
    (src / "n_amplitude.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    (src / "o_depth.png").write_bytes((src / "b_depth.png").read_bytes())  # no partner: error
    # a PNG whose header is whole and whose pixels are cut off: its size is still known, so
    # nothing was decoded
    cut = (src / "c_depth.png").read_bytes()
    (src / "p_depth.png").write_bytes(cut[: len(cut) // 2])
    shutil.copyfile(src / "c_amplitude.png", src / "p_amplitude.png")

    jobs = plan_jobs(str(src), str(tmp_path / "out"))
    assert [j.name for j in jobs if j.error] == ["o_depth.png"]
    groups = camera_groups(jobs, CleanConfig(height=12, width=16))
    assert [(key, [j.name for j in js]) for key, js in groups] == [
        ("png 12x16", ["a_depth.png", "c_depth.png", "p_depth.png"]),
        ("png 20x24", ["b_depth.png", "d_depth.png"]),
        ("tiff 12x16", ["e_depth.tif"]),
        ("npy 20x24", ["f_depth.npy"]),
        ("npz 12x16", ["g.npz"]),
        ("hdf5 20x24", ["h.h5"]),
        ("raw 12x16", ["i_depth.bin"]),
        ("adi_depth_ir 6x8", ["j_depth_u16le_6x8.bin"]),
        ("mkv m1.mkv", ["m1.mkv"]),
        ("mkv m2.mkv", ["m2.mkv"]),
        (f"png {UNKNOWN_SIZE}", ["n_depth.png"]),
    ]
    # raw files without a configured size cannot be told apart: one group, failing when read
    no_size = {j.name: camera_key(j, CleanConfig()) for j in jobs}
    assert no_size["i_depth.bin"] == f"raw {UNKNOWN_SIZE}"


def test_an_hdf5_file_of_several_sizes_names_them_all(tmp_path):
    import h5py

    path = tmp_path / "two.h5"
    with h5py.File(path, "w") as f:
        for name, (h, w) in (("a", (4, 6)), ("b", (8, 10)), ("c", (4, 6))):
            f.create_dataset(f"{name}/depth", data=np.ones((2, h, w), np.uint16))
            f.create_dataset(f"{name}/amplitude", data=np.ones((2, h, w), np.uint16))
    (job,) = plan_jobs(str(path), str(tmp_path / "out"))
    assert camera_key(job, CleanConfig()) == "hdf5 4x6+8x10"


def test_frame_sizes_reads_the_header_only(tmp_path):
    x = np.zeros((3, 5, 7), np.uint16)
    np.save(tmp_path / "a_depth.npy", x)
    data = (tmp_path / "a_depth.npy").read_bytes()
    (tmp_path / "a_depth.npy").write_bytes(data[: len(data) - x.nbytes + 10])  # pixels cut off
    assert frame_sizes(tmp_path / "a_depth.npy") == [(5, 7)]
    assert frame_sizes(tmp_path / "a_depth.bin") == []  # raw: no size in the file
    assert frame_sizes(tmp_path / "a_depth.bin", height=4, width=6) == [(4, 6)]
    assert frame_sizes(tmp_path / "b_depth_u16le_3x9.bin") == [(3, 9)]  # ADI: from the name
    (tmp_path / "c_depth.png").write_bytes(b"not a png")
    assert frame_sizes(tmp_path / "c_depth.png") == []


# --- the real captures: each camera as if alone ---------------------------------------------------


def _real_mixed(dst: Path, real_data) -> dict[str, list[str]]:
    """The ADI wall as a uint16-mm PNG pair, the ADI office interleaved file and the Azure Kinect
    .mkv in one folder; returns the files of each camera group (relative paths)."""
    depth, ir = real_data.adi_wall()
    _png_pair(dst / "adi", "wall", depth[0, 0].numpy(), ir[0, 0].numpy())
    for rel, to in ((OFFICE, "adi/office_mode3_interleaved_512x512.bin"), (MKV, "kinect/desk.mkv")):
        (dst / to).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(real_capture(rel), dst / to)
    return {
        "adi_interleaved 512x512": ["adi/office_mode3_interleaved_512x512.bin"],
        "png 512x512": ["adi/wall_depth.png", "adi/wall_amplitude.png"],
        "mkv kinect/desk.mkv": ["kinect/desk.mkv"],
    }


def test_real_cameras_mixed_in_one_folder_come_out_as_each_alone(real_data, tmp_path, capsys):
    groups = _real_mixed(tmp_path / "in", real_data)
    out = tmp_path / "out"
    assert main(["clean", str(tmp_path / "in"), str(out), "--quiet", "--no-figure"]) == 0
    text = capsys.readouterr().out.splitlines()
    together = tree(out)
    records = _records(out)
    for i, (key, files) in enumerate(groups.items()):
        alone_in, alone_out = tmp_path / f"alone{i}", tmp_path / f"alone{i}_out"
        for rel in files:
            (alone_in / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(tmp_path / "in" / rel, alone_in / rel)
        assert main(["clean", str(alone_in), str(alone_out), "--quiet", "--no-figure"]) == 0
        alone_text = capsys.readouterr().out.splitlines()
        alone = tree(alone_out)
        outputs = [k for k in alone if k != "clean.toml"]
        assert outputs and all(together[k] == alone[k] for k in outputs), (key, outputs)
        # the same stage, measured on the same frames: the camera's line is the one alone
        assert f"camera {key} (1 file(s)): {alone_text[1]}" in text
        rec, rec_alone = records[files[0]], _records(alone_out)[files[0]]
        assert rec["camera"] == key and rec["report"] == rec_alone["report"]
    start = _start(out)
    assert start["pipeline"] is None
    assert [(c["key"], c["files"]) for c in start["cameras"]] == [(k, 1) for k in groups]
    # the wall's stripes were removed; the recording's depth is not the wall's destriper's
    wall = records["adi/wall_depth.png"]["report"]["stripes"]["columns"]
    assert wall["after_mm2"] < 0.1 * wall["before_mm2"]
    assert start["cameras"][1]["pipeline"]["destripe"] is not None
    assert start["cameras"][2]["pipeline"]["calibration"]["camera"] == "azure_kinect"


# --- two synthetic cameras: one striped, one clean ------------------------------------------------


def _clean_camera(folder: Path, n: int = 2) -> None:
    """``n`` stripe-free 24 x 36 frames (a scene with noise): the default stage finds nothing."""
    for i in range(n):
        sc = synthetic_scene(24, 36, seed=60 + i)
        g = torch.Generator().manual_seed(i)
        x = add_depth_noise(sc.depth, sc.amplitude, 0.3**2, amplitude_floor=5.0, generator=g)
        d = np.rint(np.nan_to_num(x[0, 0].numpy(), nan=0.0) * 1e3).clip(0, 65535)
        _png_pair(folder, f"a{i}", d, np.rint(sc.amplitude[0, 0].numpy()))


def _striped_camera(folder: Path, n: int = 3) -> None:
    """``n`` 32 x 40 frames with strong column stripes (10 mm at pi, 6 mm at 2 pi / 3)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    for i in range(n):
        d, a = frame(rng)
        tio.write_pair(folder / f"b{i}_depth.png", d, a, folder / f"b{i}_amplitude.png")


@pytest.fixture
def two_cameras(tmp_path) -> Path:
    """The clean camera's files first in file order: a stage measured on the first frames of the
    whole folder (the clean camera's) would leave the striped camera's files uncleaned."""
    src = tmp_path / "in"
    _clean_camera(src)
    _striped_camera(src)
    return src


def test_a_stripe_free_camera_beside_a_striped_one(two_cameras, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["clean", str(two_cameras), str(out), "--quiet", "--no-figure"]) == 0
    lines = capsys.readouterr().out.splitlines()
    stages = [x for x in lines if x.startswith("camera ")]
    assert len(stages) == 2 and lines[1:3] == stages, lines
    assert stages[0].startswith("camera png 24x36 (2 file(s)): stage auto, measured on 2")
    assert "nothing to do" in stages[0] and "the outputs equal the inputs" in stages[0]
    assert stages[1].startswith("camera png 32x40 (3 file(s)): stage auto, measured on 3")
    assert "notch" in stages[1] and "nothing to do" not in stages[1]
    for i in range(2):  # the clean camera: byte for byte
        for kind in ("depth", "amplitude"):
            name = f"a{i}_{kind}.png"
            assert (out / name).read_bytes() == (two_cameras / name).read_bytes(), name
    records = _records(out)
    for i in range(3):  # the striped camera: cleaned
        rec = records[f"b{i}_depth.png"]
        assert rec["camera"] == "png 32x40" and rec["report"]["changed"] > 0.5
        assert (out / f"b{i}_depth.png").read_bytes() != (
            two_cameras / f"b{i}_depth.png"
        ).read_bytes()
    assert {records[f"a{i}_depth.png"]["camera"] for i in range(2)} == {"png 24x36"}
    cams = _start(out)["cameras"]
    assert [(c["key"], c["files"]) for c in cams] == [("png 24x36", 2), ("png 32x40", 3)]
    assert cams[0]["pipeline"]["notch"] is None and cams[1]["pipeline"]["notch"] is not None


def test_one_camera_prints_and_records_as_before(tmp_path, capsys):
    src = tmp_path / "in"
    _striped_camera(src)
    out = tmp_path / "out"
    assert main(["clean", str(src), str(out), "--quiet", "--no-figure"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].startswith("stage auto, measured on 3 calibration frame(s): notch")
    assert not any(x.startswith("camera ") for x in lines)
    start = _start(out)
    assert start["pipeline"]["notch"] is not None
    assert start["cameras"] == [{"key": "png 32x40", "files": 3, "pipeline": start["pipeline"]}]
    assert {r["camera"] for r in _records(out).values()} == {"png 32x40"}


@pytest.mark.parametrize(
    "kw", [{"workers": 2}, {"workers": 2, "compute_in_workers": False}], ids=["in-workers", "main"]
)
def test_local_engine_workers_use_each_cameras_pipeline(two_cameras, tmp_path, kw):
    config = CleanConfig(batch=2)
    serial = clean(str(two_cameras), str(tmp_path / "serial"), config, device="cpu", figure=False)
    parallel = clean(str(two_cameras), str(tmp_path / "par"), config, device="cpu", figure=False,
                     **kw)  # fmt: skip
    assert (serial.done, parallel.done) == (5, 5)
    assert tree(tmp_path / "par") == tree(tmp_path / "serial")
    assert (tmp_path / "par" / "a0_depth.png").read_bytes() == (
        two_cameras / "a0_depth.png"
    ).read_bytes()


def _rounded(value):
    """``value`` with every float rounded to 6 significant digits (nested dicts and lists)."""
    if isinstance(value, float):
        return float(f"{value:.6g}")
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def test_a_resumed_run_rebuilds_the_same_cameras(two_cameras, tmp_path):
    out = tmp_path / "out"
    first = clean(str(two_cameras), str(out), figure=False)
    assert first.done == 5
    before = tree(out)
    os.remove(out / "b1_depth.png")  # unfinished now
    again = clean(str(two_cameras), str(out), figure=False)
    assert (again.done, again.already_done) == (1, 4)
    assert tree(out) == before
    starts = [r for r in read_manifest(str(out / "manifest.jsonl")) if r.get("event") == "start"]
    # the same groups and stages (measured values to 6 digits: multi-threaded reductions of the
    # measurement may differ in the last bits between runs; the bytes written did not)
    assert len(starts) == 2 and _rounded(starts[0]["cameras"]) == _rounded(starts[1]["cameras"])
    last = [r for r in read_manifest(str(out / "manifest.jsonl")) if r.get("file")][-1]
    assert last["file"] == "b1_depth.png" and last["camera"] == "png 32x40"


# --- a camera with nothing to measure on ----------------------------------------------------------


def _eight_bit(folder: Path, name: str, size: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((size, size), 100, np.uint8)).save(folder / f"{name}_depth.png")
    Image.fromarray(np.full((size, size), 90, np.uint8)).save(folder / f"{name}_amplitude.png")


def test_a_camera_with_no_frame_to_measure_on_gets_no_stage(tmp_path, capsys):
    src = tmp_path / "in"
    _striped_camera(src)
    _eight_bit(src, "c", 20)  # unreadable (8-bit depth): its camera has nothing to measure on
    status = main(["clean", str(src), str(tmp_path / "out"), "--quiet", "--no-figure"])
    lines = capsys.readouterr().out.splitlines()
    assert status == 1
    assert lines[2] == f"camera png 20x20 (1 file(s)): stage auto: nothing measured ({UNMEASURED})"
    assert lines[1].startswith("camera png 32x40 (3 file(s)): stage auto, measured on 3")
    records = _records(tmp_path / "out")
    assert (
        records["c_depth.png"]["status"] == "failed" and "8-bit" in records["c_depth.png"]["error"]
    )
    assert all(records[f"b{i}_depth.png"]["report"]["changed"] > 0.5 for i in range(3))
    cams = _start(tmp_path / "out")["cameras"]
    assert cams[1]["key"] == "png 20x20" and cams[1]["note"] == UNMEASURED
    assert "note" not in cams[0]


def test_no_camera_with_a_frame_lists_every_files_reason_in_file_order(tmp_path):
    src = tmp_path / "in"
    _eight_bit(src, "x0", 20)
    _eight_bit(src, "x1", 30)  # another camera, unreadable too
    _eight_bit(src, "x2", 20)
    (src / "x3_depth.png").write_bytes((src / "x0_depth.png").read_bytes())  # no partner
    with pytest.raises(NoFramesError) as info:
        clean(str(src), str(tmp_path / "out"))
    names = [name for name, _ in info.value.failures]
    assert names == ["x0_depth.png", "x1_depth.png", "x2_depth.png", "x3_depth.png"]
    assert not (tmp_path / "out").exists()  # refused before anything was written


# --- the Ray engine -------------------------------------------------------------------------------


@pytest.mark.slow  # a local Ray instance
def test_ray_engine_runs_each_camera_with_its_pipeline(two_cameras, tmp_path):
    import ray

    root = Path(__file__).resolve().parents[1]
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": str(root)}})  # fmt: skip
    try:
        config = CleanConfig(batch=2)
        local = clean(str(two_cameras), str(tmp_path / "local"), config, figure=False)
        remote = clean(str(two_cameras), str(tmp_path / "ray"), config, engine="ray",
                       concurrency=1, figure=False)  # fmt: skip
    finally:
        ray.shutdown()
    assert (local.done, remote.done) == (5, 5)
    assert tree(tmp_path / "ray") == tree(tmp_path / "local")
    assert (tmp_path / "ray" / "a1_depth.png").read_bytes() == (
        two_cameras / "a1_depth.png"
    ).read_bytes()
