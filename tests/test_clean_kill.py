"""Must-show of issue 9.3: ``tof-fpn clean`` killed half-way (SIGKILL, SIGTERM) and restarted ends
with an output tree byte-identical to an uninterrupted run's, no file lost, corrupt or done twice.

The run is a real subprocess (``python -m tof_fpn_torch clean``, this checkout's code) with two
DataLoader workers on 300 small PNG pairs; the signal is sent when a third to two thirds of the
files are recorded done.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from _clean_data import png_folder, tree

from tof_fpn_torch.clean import CleanConfig, clean

pytestmark = pytest.mark.slow  # 300-file runs killed and restarted: `python -m pytest -m slow`

ROOT = Path(__file__).resolve().parents[1]
N = 300
FLAGS = ["--batch", "4", "--denoise", "nlm", "--denoise-opt", "patch_distance=4"]
CONFIG = CleanConfig(batch=4, denoise="nlm", denoise_options={"patch_distance": 4})


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    root = tmp_path_factory.mktemp("kill")
    src = png_folder(root / "in", N, h=24, w=32, sub_every=5)
    ref = clean(str(src), str(root / "ref"), CONFIG, workers=2, device="cpu")
    assert ref.status == 0 and ref.done == N
    return src, tree(root / "ref")


def _done_lines(manifest: Path) -> int:
    try:
        return manifest.read_bytes().count(b'"status": "done"')
    except FileNotFoundError:
        return 0


def _start(src, out):
    cmd = [sys.executable, "-m", "tof_fpn_torch", "clean", str(src), str(out), "--quiet"]
    return subprocess.Popen(
        [*cmd, "--workers", "2", "--device", "cpu", *FLAGS],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _kill_half_way(proc, manifest: Path, sig: int) -> int:
    deadline = time.monotonic() + 120
    while _done_lines(manifest) < N // 3:
        assert proc.poll() is None, ("finished before the kill", proc.communicate())
        assert time.monotonic() < deadline, "no progress"
        time.sleep(0.005)
    proc.send_signal(sig)
    proc.wait(timeout=60)
    at_kill = _done_lines(manifest)
    assert at_kill < N, "the run finished before the signal took effect: nothing tested"
    return at_kill


def _records(manifest: Path) -> list[dict]:
    return [json.loads(s) for s in manifest.read_text().splitlines() if s.strip()]


def _check_restart(src, out, ref_tree, first_done: int):
    again = subprocess.run(
        [sys.executable, "-m", "tof_fpn_torch", "clean", str(src), str(out), "--quiet"]
        + ["--workers", "2", "--device", "cpu", *FLAGS],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert again.returncode == 0, again.stderr
    assert f"{first_done} already done" in again.stdout
    assert tree(out) == ref_tree  # every file there, byte for byte; nothing else (no .tmp)
    done = [r["file"] for r in _records(out / "manifest.jsonl") if r.get("status") == "done"]
    assert len(done) == len(set(done)) == N  # each file done exactly once over both runs


def test_sigkill_half_way_then_restart_is_byte_identical(frames, tmp_path):
    src, ref_tree = frames
    out = tmp_path / "out"
    proc = _start(src, out)
    first_done = _kill_half_way(proc, out / "manifest.jsonl", signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    # every file recorded done is complete and right; nothing is half-written under a real name
    recs = _records(out / "manifest.jsonl")
    assert recs[-1].get("event") != "end"  # killed: no end record
    for rec in recs:
        if rec.get("status") == "done":
            for name in rec["outputs"]:
                assert (out / name).read_bytes() == ref_tree[name]
    for p in out.rglob("*"):
        if p.is_file() and not p.name.startswith(".") and p.suffix == ".png":
            assert p.read_bytes() == ref_tree[p.relative_to(out).as_posix()]
    _check_restart(src, out, ref_tree, first_done)


def test_sigterm_ends_cleanly_then_restart_is_byte_identical(frames, tmp_path):
    src, ref_tree = frames
    out = tmp_path / "out"
    proc = _start(src, out)
    _kill_half_way(proc, out / "manifest.jsonl", signal.SIGTERM)
    stdout, stderr = proc.communicate()
    assert proc.returncode == 128 + signal.SIGTERM
    err = stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tof-fpn clean: error: stopped by SIGTERM"), err
    recs = _records(out / "manifest.jsonl")
    assert recs[-1]["event"] == "end" and recs[-1]["interrupted"] == signal.SIGTERM
    first_done = sum(1 for r in recs if r.get("status") == "done")
    assert recs[-1]["done"] == first_done and first_done < N
    assert not [p for p in out.rglob("*.tmp")]  # clean end: no temporaries left
    for rec in recs:
        if rec.get("status") == "done":
            for name in rec["outputs"]:
                assert (out / name).read_bytes() == ref_tree[name]
    # files written by a worker after the last record are complete too (atomic renames)
    for p in out.rglob("*.png"):
        assert p.read_bytes() == ref_tree[p.relative_to(out).as_posix()]
    _check_restart(src, out, ref_tree, first_done)
    assert os.path.isfile(out / "clean.toml")
