"""The training example beside the package (``examples/front_ends.py``,
``examples/train_front_ends.py``): its evaluation and a quick end-to-end run, as the README
shows it."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from front_ends import evaluate

from tof_fpn_torch.cli import main as cli_main
from tof_fpn_torch.learn import FRONT_ENDS, DepthModel, DnCNN

ROOT = Path(__file__).resolve().parents[2]
THRESHOLDS = (15.8, 79.2)  # simulator DN, as measured by front_ends.fusion_thresholds()


def test_identity_model_evaluates_as_its_input():
    model = DepthModel(DnCNN(3, 4))  # zero last layer: the identity
    ev = evaluate(model, 2, (32, 32), THRESHOLDS[1])
    assert ev["model"] == pytest.approx(ev["input"], abs=1e-9)
    assert ev["model_low"] == pytest.approx(ev["input_low"], abs=1e-9)
    assert 0.0 < ev["low_share"] <= 1.0


@pytest.mark.slow
def test_quick_example_runs_end_to_end(tmp_path):
    out = tmp_path / "learn"
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "examples" / "train_front_ends.py"),
            "--quick",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads((out / "learn.json").read_text())
    assert set(res["runs"]) == set(FRONT_ENDS)
    for items in res["runs"].values():
        it = items[0]
        assert len(it["losses"]) == res["settings"]["steps"]
        assert all(math.isfinite(v) for v in it["losses"])
        assert math.isfinite(it["adi"]["reduction_db"])
    ex = res["runs"]["trainable"][0]["export"]  # the whole model, trained stage + network
    assert ex["torchscript_max_diff"] <= 1e-5 and ex["torchscript_invalid_kept"]
    assert ex["onnx_max_diff"] <= 1e-5 and ex["onnx_invalid_kept"]
    assert max(res["runs"]["trainable"][0]["taps"]["notch_gains"]) < 1e-5
    assert (out / "curves.png").stat().st_size > 1000
    # the report shows the JSON's numbers, a row per front end
    report = (out / "report.md").read_text()
    rows = {ln.split("|")[1].strip(): ln for ln in report.splitlines() if ln.startswith("| ")}
    for front, summary in res["summary"].items():
        assert f"{summary['model_low'][0]:.2f}" in rows[front]
        assert f"{summary['model'][0]:.2f}" in rows[front]
    for front in FRONT_ENDS:
        assert (out / f"model_{front.replace('+', '_')}.pt").is_file()
    # the README's learn command, as written, on this output (--quick added, paths moved here)
    text = (ROOT / "README.md").read_text()
    block = text.split("<!-- learn-command -->", 1)[1].split("```bash\n", 1)[1].split("\n```")[0]
    train_cmd, export_cmd = (c.split() for c in block.split(" && "))
    assert train_cmd[:2] == ["python", "examples/train_front_ends.py"] and "--out" in train_cmd
    assert export_cmd[:2] == ["tof-fpn", "export"]
    readme_out = train_cmd[train_cmd.index("--out") + 1]
    args = [str(out) + a[len(readme_out) :] if a.startswith(readme_out) else a for a in export_cmd]
    args[args.index("--out") + 1] = str(tmp_path / "model.pt")
    assert cli_main(args[1:]) == 0 and (tmp_path / "model.pt").is_file()
