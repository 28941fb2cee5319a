"""``tof-fpn clean``: the same input gives the same output bytes whatever the batch size (files per
group), the worker count and the engine. Batched torch kernels differ in the last bits between
batch sizes, so the frames of one file and of different files must not meet in a batch that
depends on these settings."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from _clean_data import frame, png_folder, tree

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import CleanConfig, clean
from tof_fpn_torch.clean.manifest import read_manifest

ROOT = Path(__file__).resolve().parents[1]
SHAPE, ODD = (60, 80), (61, 81)
#: per file, everything but timing and the run's own settings (``clean.toml`` holds ``batch``)
SKIP = ("manifest.jsonl", "clean.toml", "report.png")
#: the depth files whose frames the FPN stage must change (else the test would prove nothing)
STRIPED = (
    "f000_depth.png",
    "sub/f004_depth.png",
    "odd/f002_depth.png",
    "stack3.npz",
    "stack4_float.npz",
)


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """Striped frames in three cameras: PNG pairs of two sizes and multi-frame ``.npz`` files
    (their frames mix across files in a batch of 7), one of them float32 (every last bit kept), one
    with a frame without a valid pixel. Which batch sizes change the last bits of which frames
    depends on the shapes and the data: with the frames batched per group, ``--batch 7`` changed
    the ``.npz`` files here and ``--batch 3`` the 60 x 80 PNG files."""
    root = tmp_path_factory.mktemp("bytes") / "in"
    png_folder(root, 8, h=SHAPE[0], w=SHAPE[1], sub_every=3)
    png_folder(root / "odd", 4, seed=1, h=ODD[0], w=ODD[1], sub_every=0)
    rng = np.random.default_rng(11)
    for name, n, dtype in (("stack3", 3, "uint16"), ("stack2", 2, "uint16")):
        d, a = zip(*(frame(rng, *ODD) for _ in range(n)), strict=True)
        tio.write_npz(root / f"{name}.npz", np.stack(d), np.stack(a), dtype=dtype)
    d, a = zip(*(frame(rng, *ODD) for _ in range(4)), strict=True)
    d = np.stack(d)
    d[2] = np.nan  # no valid pixel: passes as it is
    tio.write_npz(root / "stack4_float.npz", d, np.stack(a), dtype="float32")
    return root


@pytest.fixture(scope="module")
def reference(folder, tmp_path_factory) -> Path:
    """The folder cleaned file by file, frame by frame: ``--batch 1``, no worker."""
    out = tmp_path_factory.mktemp("bytes") / "batch1"
    rep = clean(str(folder), str(out), CleanConfig(batch=1), device="cpu", figure=False)
    assert (rep.status, rep.done, rep.frames) == (0, 15, 21), rep.summary()
    return out


def _records(out: Path) -> dict[str, dict]:
    """Each file's manifest record without its timing (the ``report`` values included)."""
    recs = {}
    for rec in read_manifest(os.path.join(out, "manifest.jsonl")):
        if "file" in rec:
            recs[rec["file"]] = {
                k: v for k, v in rec.items() if k != "time" and not k.endswith("_s")
            }
    return recs


def _same(out: Path, reference: Path) -> None:
    got, want = tree(out, skip=SKIP), tree(reference, skip=SKIP)
    assert sorted(got) == sorted(want)
    differ = [name for name in want if got[name] != want[name]]
    assert differ == [], f"output bytes differ from --batch 1: {differ}"
    assert _records(out) == _records(reference)


def test_the_reference_run_changes_the_striped_frames(folder, reference):
    outputs = tree(reference, skip=SKIP)
    for name in STRIPED:
        assert outputs[name] != (folder / name).read_bytes(), name
    recs = _records(reference)
    assert all(r["status"] == "done" for r in recs.values()) and len(recs) == 15
    assert recs["stack4_float.npz"]["empty_frames"] == 1
    assert recs["stack3.npz"]["report"]["changed"] > 0.5  # most valid pixels moved


def test_batch_and_workers_do_not_change_the_bytes(folder, reference, tmp_path):
    out = tmp_path / "batch7"
    rep = clean(str(folder), str(out), CleanConfig(batch=7), workers=2, device="cpu", figure=False)
    assert rep.status == 0 and rep.done == 15
    _same(out, reference)


@pytest.mark.slow  # a local Ray instance (about half a minute)
def test_the_ray_engine_writes_the_same_bytes(folder, reference, tmp_path):
    import ray

    ray.init(
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        runtime_env={"env_vars": {"PYTHONPATH": str(ROOT)}},
    )
    try:
        out = tmp_path / "ray"
        rep = clean(
            str(folder), str(out), CleanConfig(batch=3), engine="ray", concurrency=2, figure=False
        )
    finally:
        ray.shutdown()
    assert rep.status == 0 and rep.done == 15
    _same(out, reference)
