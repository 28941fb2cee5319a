"""TorchScript and ONNX export: exported graphs agree with eager; the traced path == fast path; CLI."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import torch

from tof_fpn_torch import FPNFilter
from tof_fpn_torch.build import suppression_from_design
from tof_fpn_torch.cli import main
from tof_fpn_torch.export import export_onnx, export_torchscript

# the module, not the function of the same name that the package exports
fpn_filter_module = importlib.import_module("tof_fpn_torch.runtime.fpn_filter")


def _inputs(shape, seed=0, holes=True):
    g = torch.Generator().manual_seed(seed)
    depth = 1.0 + torch.rand(shape, generator=g)
    amplitude = 400.0 * torch.rand(shape, generator=g)
    if holes:
        depth[0, 0, 2, 3] = float("nan")
        depth[-1, 0, 5, 7:11] = 0.0
    return depth, amplitude


def test_traced_path_equals_fast_path(monkeypatch):
    """While tracing for export the stage takes its branch-free, out-of-place path (fill always
    on, block-Toeplitz GEMM); it must give the fast path's output."""
    m = suppression_from_design(order=41, rho=0.12, dim=(-2, -1))
    for holes in (False, True):
        d, a = _inputs((2, 1, 50, 90), holes=holes)
        with torch.inference_mode():
            fast = m(d, a)
            monkeypatch.setattr(fpn_filter_module, "_tracing", lambda: True)
            traced = m(d, a)
            monkeypatch.undo()
        torch.testing.assert_close(traced, fast, rtol=0, atol=2e-6, equal_nan=True)


def test_torchscript_file_roundtrip(tmp_path):
    m = suppression_from_design()
    path = tmp_path / "fpn.pt"
    export_torchscript(m, path)
    loaded = torch.jit.load(str(path))
    d, a = _inputs((2, 1, 30, 64))
    torch.testing.assert_close(loaded(d, a), m(d, a), rtol=0, atol=0, equal_nan=True)


@pytest.fixture(scope="module")
def cli_onnx(tmp_path_factory):
    path = tmp_path_factory.mktemp("onnx") / "fpn.onnx"
    assert (
        main(
            [
                "export",
                "--format",
                "onnx",
                "--out",
                str(path),
                "--order",
                "41",
                "--rho",
                "0.12",
                "--opset",
                "17",
            ]
        )
        == 0
    )
    return path


@pytest.mark.parametrize("shape", [(2, 1, 64, 80), (1, 1, 33, 47), (3, 1, 8, 200)])
def test_onnx_agrees_with_eager_dynamic_shapes(cli_onnx, shape):
    import onnx
    import onnxruntime as ort

    model = onnx.load(str(cli_onnx))
    assert [o.version for o in model.opset_import if o.domain in ("", "ai.onnx")] == [17]
    sess = ort.InferenceSession(str(cli_onnx))
    d, a = _inputs(shape)
    (out,) = sess.run(None, {"depth": d.numpy(), "amplitude": a.numpy()})
    ref = suppression_from_design(order=41, rho=0.12)(d, a).numpy()
    np.testing.assert_array_equal(np.isnan(out), np.isnan(ref))
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5, equal_nan=True)


def test_cli_torchscript(tmp_path, capsys):
    path = tmp_path / "m.pt"
    assert (
        main(
            [
                "export",
                "--format",
                "torchscript",
                "--out",
                str(path),
                "--dim",
                "rows",
                "--no-adaptive",
            ]
        )
        == 0
    )
    assert '"format": "torchscript"' in capsys.readouterr().out
    d, a = _inputs((1, 1, 40, 30))
    ref = suppression_from_design(dim=-2, adaptive=False)(d, a)
    torch.testing.assert_close(torch.jit.load(str(path))(d, a), ref, rtol=0, atol=0, equal_nan=True)


def test_cli_bad_input_is_one_line_error(tmp_path, capsys):
    assert (
        main(["export", "--format", "onnx", "--out", str(tmp_path / "x.onnx"), "--opset", "13"])
        == 2
    )
    err = capsys.readouterr().err
    assert "opset must be an int >= 17, got 13" in err and "Traceback" not in err
    assert (
        main(["export", "--format", "torchscript", "--out", str(tmp_path / "y.pt"), "--rho", "0.9"])
        == 2
    )


def test_export_onnx_rejects_non_module(tmp_path):
    with pytest.raises(ValueError, match="torch.nn.Module"):
        export_onnx("not a module", tmp_path / "z.onnx")
    with pytest.raises(ValueError, match="torch.nn.Module"):
        export_torchscript(FPNFilter)  # the class, not an instance


def test_design_survives_torchscript_and_onnx(tmp_path, cli_onnx):
    import json

    import onnx

    m = suppression_from_design(order=28, rho=0.13)
    path = tmp_path / "m.pt"
    export_torchscript(m, path)
    loaded = torch.jit.load(str(path))
    assert (loaded.filter.order, loaded.filter.rho) == (28, 0.13)
    assert loaded.filter.notches == list(m.filter.notches) and len(loaded.filter.notches) == 2
    meta = {p.key: json.loads(p.value) for p in onnx.load(str(cli_onnx)).metadata_props}
    assert meta["filter.order"] == 41 and meta["filter.rho"] == 0.12
    assert meta["filter.notches"] == pytest.approx([2 * np.pi / 3, np.pi])
    assert meta["filter.dims"] == [-1] and meta["filter.delay"] == 0.0  # odd order: compensated
    assert meta["filter.compensated"] is True


@pytest.mark.parametrize("shape", [(2, 1, 64, 80), (1, 1, 33, 47)])
def test_onnx_agrees_with_eager_with_the_gate_open(cli_onnx, shape):
    """Striped frames open the stripe gate: the exported gate must compute what eager does."""
    import onnxruntime as ort

    d, a = _inputs(shape)
    n = torch.arange(shape[-1], dtype=d.dtype)
    d = d + 0.2 * torch.cos(np.pi * n) + 0.2 * torch.cos(2 * np.pi / 3 * n)
    a = 0.2 * a  # low amplitude: the fusion filters fully
    m = suppression_from_design(order=41, rho=0.12)
    with torch.inference_mode():
        ref = m(d, a)
        m.gate = False
        ungated = m(d, a)
    assert torch.equal(ref.isnan(), ungated.isnan())
    torch.testing.assert_close(ref, ungated, equal_nan=True)  # the gate is fully open here
    (out,) = ort.InferenceSession(str(cli_onnx)).run(
        None, {"depth": d.numpy(), "amplitude": a.numpy()}
    )
    np.testing.assert_allclose(out, ref.numpy(), rtol=0, atol=1e-5, equal_nan=True)


def test_onnx_agrees_with_eager_with_the_gate_half_open(cli_onnx):
    """Weaker stripes: 0 < g < 1, so the exported statistic itself is compared, not a clamp."""
    import onnxruntime as ort

    d, a = _inputs((2, 1, 64, 80), holes=False)
    n = torch.arange(80, dtype=d.dtype)
    d = d + 0.05 * torch.cos(np.pi * n)
    a = 0.2 * a
    m = suppression_from_design(order=41, rho=0.12)
    with torch.inference_mode():
        ref = m(d, a)
        m.gate = False
        full = m(d, a)
    g = ((ref - d) / (full - d)).flatten(1).median(1).values
    assert bool(((g > 0.05) & (g < 0.95)).all()), g
    (out,) = ort.InferenceSession(str(cli_onnx)).run(
        None, {"depth": d.numpy(), "amplitude": a.numpy()}
    )
    np.testing.assert_allclose(out, ref.numpy(), rtol=0, atol=1e-5)


def test_onnx_refuses_the_single_frame_destriper_with_a_reason(tmp_path):
    from tof_fpn_torch.runtime import Destripe

    stage = suppression_from_design(destripe=Destripe())
    with pytest.raises(ValueError, match="TorchScript.*FixedPatternCorrection"):
        export_onnx(stage, tmp_path / "d.onnx")
    scripted = export_torchscript(stage)  # TorchScript takes it
    d, a = _inputs((1, 1, 40, 64), holes=False)
    torch.testing.assert_close(scripted(d, a), stage(d, a), rtol=0, atol=0)
