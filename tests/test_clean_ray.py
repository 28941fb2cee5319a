"""``tof-fpn clean --engine ray`` on a local Ray instance (2 CPUs, no dashboard): the same files as
the local engine, byte for byte, the same manifest logic and resume. Ray is a test dependency:
these tests fail (not skip) without it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import ray
from _clean_data import frame, png_folder, tree

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import CleanConfig, clean
from tof_fpn_torch.clean.manifest import read_manifest
from tof_fpn_torch.cli import main

pytestmark = pytest.mark.slow  # a local Ray instance: `python -m pytest -m slow` runs them

ROOT = Path(__file__).resolve().parents[1]
CONFIG = CleanConfig(destripe="columns", batch=4)


@pytest.fixture(scope="module")
def local_ray():
    # the workers import this checkout's package (an installed copy elsewhere would not do)
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        runtime_env={"env_vars": {"PYTHONPATH": str(ROOT)}},
    )
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    """PNG pairs in two shapes, an .npz of three frames, an HDF5 file, one corrupt file."""
    root = tmp_path_factory.mktemp("mixed") / "in"
    png_folder(root, 9, sub_every=3)
    png_folder(root / "wide", 4, seed=1, h=20, w=48, sub_every=0)
    rng = np.random.default_rng(5)
    d, a = zip(*(frame(rng) for _ in range(3)), strict=True)
    tio.write_npz(root / "stack.npz", np.stack(d), np.stack(a))
    tio.write_hdf5(root / "one.h5", d[0], a[0], dtype="float32")
    (root / "broken_depth.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    (root / "broken_amplitude.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    return root


def test_ray_and_local_engines_write_the_same_bytes(local_ray, mixed, tmp_path):
    local = clean(str(mixed), str(tmp_path / "local"), CONFIG, workers=2, device="cpu")
    remote = clean(str(mixed), str(tmp_path / "ray"), CONFIG, engine="ray", concurrency=1)
    for rep in (local, remote):
        assert (rep.done, rep.failed, rep.frames) == (15, 1, 17), rep
    assert tree(tmp_path / "ray") == tree(tmp_path / "local")
    recs = read_manifest(str(tmp_path / "ray" / "manifest.jsonl"))
    assert recs[0]["engine"] == "ray" and recs[-1]["event"] == "end"
    failed = [r for r in recs if r.get("status") == "failed"]
    assert [r["file"] for r in failed] == ["broken_depth.png"] and "cannot read" in failed[0][
        "error"
    ]


def test_ray_resumes_like_the_local_engine(local_ray, mixed, tmp_path, capsys):
    ref = tmp_path / "ref"
    clean(str(mixed), str(ref), CONFIG)
    out = tmp_path / "out"
    argv = ["clean", mixed, out, "--engine", "ray", "--concurrency", "1", "--quiet"]
    argv += ["--destripe", "columns", "--batch", "4"]
    assert main([str(a) for a in argv]) == 1  # the broken file
    for name in ("f003_depth.png", "wide/f002_depth.png", "stack.npz"):
        (out / name).unlink()
    assert main([str(a) for a in argv]) == 1
    stdout = capsys.readouterr().out
    assert "cleaned 3 file(s) (5 frames)" in stdout and "12 already done" in stdout
    assert tree(out) == tree(ref)
    done = [
        r["file"] for r in read_manifest(str(out / "manifest.jsonl")) if r.get("status") == "done"
    ]
    assert len(done) == 15 + 3 and len(set(done)) == 15
