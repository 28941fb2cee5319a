"""The stage in front of learned networks (issue 12): dataset, trainable stage, whole-model export."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from tof_fpn_torch.build import suppression_from_design, trainable_suppression
from tof_fpn_torch.cli import main as cli_main
from tof_fpn_torch.design import fixed_zero_taps
from tof_fpn_torch.export import export_onnx, export_torchscript
from tof_fpn_torch.learn import (
    FRONT_ENDS,
    DepthModel,
    Ranges,
    Settings,
    SimulatedFrames,
    draw_sample,
    load_model,
    make_model,
    save_model,
)
from tof_fpn_torch.runtime import (
    AmplitudeFusion,
    FPNFilter,
    KeepZeros,
    TrainableFusion,
    freeze,
    keep_zeros,
)

ROOT = Path(__file__).resolve().parents[1]
THRESHOLDS = (15.8, 79.2)  # simulator DN, as measured by learn.fusion_thresholds()


def _stream(ds, workers):
    loader = DataLoader(ds, batch_size=None, num_workers=workers)
    return [tuple(t.clone() for t in item) for item in loader]


def _same(a, b) -> bool:
    return all(
        torch.equal(x.nan_to_num(nan=-7.0), y.nan_to_num(nan=-7.0))
        for x, y in zip(a, b, strict=True)
    )


def _notch_gains(taps: torch.Tensor, notches=(2 * math.pi / 3, math.pi)) -> list[float]:
    t = taps.detach().double().numpy()
    return [abs(np.exp(-1j * w * np.arange(t.size)) @ t) for w in notches]


def _frames(b=2, h=24, w=40, seed=0):
    g = torch.Generator().manual_seed(seed)
    n = torch.arange(w, dtype=torch.float32)
    depth = 2.0 + 0.02 * torch.randn(b, 1, h, w, generator=g) + 0.05 * torch.cos(math.pi * n)
    amp = 5.0 + 60.0 * torch.rand(b, 1, h, w, generator=g)
    depth[0, 0, 3, 4] = float("nan")
    depth[-1, 0, 5, 6:9] = 0.0
    return depth, amp


def _perturbed(model: DepthModel, seed: int = 0) -> DepthModel:
    """Give the zero-initialised last layer weights, so the network is not the identity."""
    g = torch.Generator().manual_seed(seed)
    last = model.network.net[-1]
    with torch.no_grad():
        last.weight.copy_(0.01 * torch.randn(last.weight.shape, generator=g))
    return model


# ---------------------------------------------------------------------------- the dataset


def test_dataset_same_seed_and_workers_gives_identical_samples():
    ds = SimulatedFrames((24, 32), seed=3, length=6)
    a, b = _stream(ds, 2), _stream(ds, 2)
    assert len(a) == len(b) == 6
    assert all(_same(x, y) for x, y in zip(a, b, strict=True))


def test_dataset_workers_yield_different_samples_and_the_same_set_as_one_process():
    ds = SimulatedFrames((24, 32), seed=3, length=6)
    two = _stream(ds, 2)
    one = _stream(ds, 0)
    # no two samples alike (a worker split that repeats indices would duplicate them)
    for i in range(len(two)):
        for j in range(i + 1, len(two)):
            assert not torch.equal(two[i][0].nan_to_num(), two[j][0].nan_to_num())
    # the union over workers is the single-process stream, each sample a function of (seed, i)
    key = [float(x[0].nan_to_num().sum()) for x in one]
    assert sorted(float(x[0].nan_to_num().sum()) for x in two) == sorted(key)
    direct = draw_sample(3, 4, (24, 32))
    assert _same(one[4], direct[:4])


def test_dataset_seeds_differ_and_items_are_consistent():
    a = next(iter(SimulatedFrames((24, 32), seed=0, length=1)))
    b = next(iter(SimulatedFrames((24, 32), seed=1, length=1)))
    assert not torch.equal(a[0].nan_to_num(), b[0].nan_to_num())
    depth, amp, target, valid = a
    assert depth.shape == amp.shape == target.shape == valid.shape == (1, 24, 32)
    assert valid.dtype == torch.bool and depth.dtype == torch.float32
    assert bool(valid.any())
    # the measured depth is near the truth where valid (a few cm of noise + FPN, not metres)
    err = (depth - target)[valid].abs().median()
    assert 1e-4 < float(err) < 0.5


def test_dataset_settings_are_drawn_from_the_ranges():
    r = Ranges()
    seen = [draw_sample(5, i, (16, 16))[4] for i in range(12)]
    for s in seen:
        assert r.integration_time_s[0] <= s["integration_time_s"] <= r.integration_time_s[1]
        assert r.illumination_power_w[0] <= s["illumination_power_w"] <= r.illumination_power_w[1]
        assert r.read_noise_e[0] <= s["read_noise_e"] <= r.read_noise_e[1]
        assert all(
            r.periodic_offset_e[0] <= v <= r.periodic_offset_e[1] for v in s["periodic_offset_e"]
        )
    assert len({s["scene"] for s in seen}) == 2  # both scene families appear
    assert len({round(s["illumination_power_w"], 6) for s in seen}) == 12


@pytest.mark.parametrize(
    "kwargs",
    [
        {"integration_time_s": (0.0, 1e-4)},
        {"read_noise_e": (5.0, 1.0)},
        {"periodic_offset_e": (0.0, math.inf)},
        {"planar_share": 1.5},
    ],
)
def test_dataset_refuses_bad_ranges(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        SimulatedFrames((16, 16), ranges=Ranges(**kwargs))


@pytest.mark.parametrize("bad", [{"size": (8, 32)}, {"seed": -1}, {"length": 1.5}])
def test_dataset_refuses_bad_arguments(bad):
    with pytest.raises(ValueError):
        SimulatedFrames(**{"size": (16, 16), **bad})


# ------------------------------------------------------------------ the trainable stage


def test_keep_zeros_starts_from_the_design_exactly():
    designed = suppression_from_design(gate=False).filter.taps.detach().clone()
    stage = trainable_suppression(gate=False)
    assert torch.allclose(stage.filter.taps.detach(), designed, atol=1e-6)
    a = torch.as_tensor(fixed_zero_taps(), dtype=torch.float64)
    g = KeepZeros(a).right_inverse(designed.double())
    assert torch.allclose(KeepZeros(a)(g), designed.double(), atol=1e-6)


def _push_towards_identity(filt: FPNFilter, steps: int = 30) -> None:
    """A loss that wants H = 1 everywhere, notches included: it moves unprotected zeros."""
    opt = torch.optim.Adam(filt.parameters(), lr=1e-2)
    x = torch.randn(4, 1, 16, 48, generator=torch.Generator().manual_seed(0))
    for _ in range(steps):
        loss = (filt(x) - x).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()


def test_zeros_hold_while_training_and_move_without_keep_zeros():
    held = trainable_suppression(gate=False).filter
    before = held.taps.detach().clone()
    _push_towards_identity(held)
    assert float((held.taps.detach() - before).abs().max()) > 1e-3  # it did train
    assert max(_notch_gains(held.taps)) < 1e-5
    assert torch.allclose(held.taps.detach(), held.taps.detach().flip(0))  # linear phase kept
    assert float(held.taps.detach().sum()) == pytest.approx(1.0, abs=1e-6)  # no depth scaling
    # the control: the same loss on the plain trainable taps moves the zeros
    free = suppression_from_design(gate=False, trainable=True).filter
    _push_towards_identity(free)
    assert max(_notch_gains(free.taps)) > 1e-2
    assert abs(float(free.taps.detach().sum()) - 1.0) > 1e-3


def test_trainable_fusion_starts_as_the_fixed_fusion_and_learns_its_thresholds():
    depth, amp = _frames()
    filtered = depth + 0.01
    fixed = AmplitudeFusion(*THRESHOLDS, 0.1)
    learnable = TrainableFusion(*THRESHOLDS, 0.1)
    ref = fixed(filtered, depth, amp)
    out = learnable(filtered, depth, amp)
    assert torch.allclose(out.nan_to_num(), ref.nan_to_num(), atol=1e-6)
    assert torch.isnan(out[0, 0, 3, 4]) and (out[1, 0, 5, 6:9] == 0).all()
    out.nan_to_num().sum().backward()
    assert all(float(p.grad.abs()) > 0 for p in learnable.parameters())
    with pytest.raises(ValueError, match="low < high"):
        TrainableFusion(50.0, 10.0, 0.1)


def test_trainable_stage_scripts_after_freeze_and_matches_eager():
    stage = trainable_suppression(low=THRESHOLDS[0], high=THRESHOLDS[1])
    _push_towards_identity(stage.filter, steps=3)
    depth, amp = _frames()
    with torch.no_grad():
        ref = stage(depth, amp)
    scripted = export_torchscript(stage)
    assert torch.allclose(scripted(depth, amp).nan_to_num(), ref.nan_to_num(), atol=1e-6)
    frozen = freeze(stage)
    assert isinstance(frozen.filter.taps, torch.nn.Parameter)
    with pytest.raises(ValueError, match="trainable=True"):
        keep_zeros(suppression_from_design().filter, fixed_zero_taps())


# -------------------------------------------------------------------- the whole model


@pytest.mark.parametrize("front", FRONT_ENDS)
def test_depth_model_keeps_invalid_pixels_bit_for_bit(front):
    model = _perturbed(make_model(front, THRESHOLDS, Settings(layers=3, channels=4)))
    depth, amp = _frames()
    with torch.no_grad():
        out = model(depth, amp)
    assert torch.isnan(out[0, 0, 3, 4]) and (out[1, 0, 5, 6:9] == 0).all()
    valid = torch.isfinite(depth) & (depth > 0)
    assert bool(torch.isfinite(out[valid]).all())
    assert float((out - depth)[valid].abs().max()) > 0  # the network does act
    with pytest.raises(ValueError, match="amplitude"):
        model(depth, amp[..., :-1])


@pytest.mark.parametrize("front", ["none", "trainable"])
def test_gradients_stay_finite_with_invalid_pixels(front):
    model = _perturbed(make_model(front, THRESHOLDS, Settings(layers=3, channels=4)))
    depth, amp = _frames()
    depth[1, 0, 7, 2] = float("inf")
    amp[0, 0, 2, 2] = float("nan")
    valid = torch.isfinite(depth) & (depth > 0) & torch.isfinite(amp)
    out = model(depth, amp)
    torch.where(valid, out - 2.0, torch.zeros_like(out)).pow(2).sum().backward()
    grads = [p.grad for p in model.parameters() if p.requires_grad]
    assert grads and all(g is not None and bool(torch.isfinite(g).all()) for g in grads)
    assert any(float(g.abs().sum()) > 0 for g in grads)


class _Trained:
    def __init__(self, model):
        self.model, self.losses = model, []


def _trained(front="trainable"):
    """Three Adam steps of a small model on simulated frames (the training loop of the example
    ``examples/front_ends.py``, in a few lines)."""
    settings = Settings(steps=3, batch=2, size=(24, 24), workers=0, layers=3, channels=8)
    torch.manual_seed(0)
    out = _Trained(make_model(front, THRESHOLDS, settings))
    opt = torch.optim.Adam(out.model.parameters(), lr=1e-3)
    data = SimulatedFrames(settings.size, seed=0, length=settings.steps * settings.batch)
    out.model.train()
    for depth, amp, target, valid in DataLoader(data, batch_size=settings.batch):
        err = torch.where(valid, out.model(depth, amp) - target, 0.0)
        loss = err.pow(2).sum() / valid.sum().clamp_min(1)
        opt.zero_grad()
        loss.backward()
        opt.step()
        out.losses.append(float(loss.detach()))
    out.model.eval()
    return out, settings


def test_training_keeps_the_zeros_and_changes_the_model():
    tr, _ = _trained()
    assert len(tr.losses) == 3 and all(math.isfinite(v) for v in tr.losses)
    assert max(_notch_gains(tr.model.front_end.filter.taps)) < 1e-5
    assert float(tr.model.network.net[-1].weight.abs().max()) > 0


@pytest.mark.slow
def test_whole_model_exports_to_torchscript_and_onnx_within_1e5_keeping_invalid(tmp_path):
    model = _perturbed(_trained()[0].model)
    depth, amp = _frames(h=24, w=40)
    with torch.no_grad():
        ref = model(depth, amp)
    ts = export_torchscript(model, tmp_path / "m.pt")
    got = torch.jit.load(str(tmp_path / "m.pt"))(depth, amp)
    assert float((got - ref).nan_to_num().abs().max()) <= 1e-5
    assert torch.isnan(got[0, 0, 3, 4]) and (got[1, 0, 5, 6:9] == 0).all()
    assert ts is not None
    import onnxruntime as ort

    path = export_onnx(model, tmp_path / "m.onnx", example_inputs=(depth, amp))
    (out,) = ort.InferenceSession(str(path)).run(
        None, {"depth": depth.numpy(), "amplitude": amp.numpy()}
    )
    out = torch.from_numpy(out)
    assert float((out - ref).nan_to_num().abs().max()) <= 1e-5
    assert torch.isnan(out[0, 0, 3, 4]) and (out[1, 0, 5, 6:9] == 0).all()
    # another size through the dynamic axes
    d2, a2 = _frames(b=1, h=30, w=36, seed=1)
    (out2,) = ort.InferenceSession(str(path)).run(
        None, {"depth": d2.numpy(), "amplitude": a2.numpy()}
    )
    with torch.no_grad():
        assert float((torch.from_numpy(out2) - model(d2, a2)).nan_to_num().abs().max()) <= 1e-5
    # export froze a copy: the model itself still trains through G with its zeros held
    assert torch.nn.utils.parametrize.is_parametrized(model.front_end.filter, "taps")


def test_checkpoint_round_trip_and_refusals(tmp_path):
    tr, settings = _trained()
    model = _perturbed(tr.model)
    path = save_model(tmp_path / "c" / "model.pt", model, "trainable", settings, THRESHOLDS)
    loaded, info = load_model(path)
    assert info["front"] == "trainable" and info["settings"] == settings
    depth, amp = _frames()
    with torch.no_grad():
        assert torch.equal(loaded(depth, amp).nan_to_num(), model(depth, amp).nan_to_num())
    assert max(_notch_gains(loaded.front_end.filter.taps)) < 1e-5
    with pytest.raises(FileNotFoundError):
        load_model(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    torch.save({"weights": torch.zeros(2)}, junk)
    with pytest.raises(ValueError, match="checkpoint"):
        load_model(junk)
    text = tmp_path / "text.pt"
    text.write_text("not a checkpoint")
    with pytest.raises(ValueError, match="not a model checkpoint"):
        load_model(text)
    with pytest.raises(ValueError, match="front"):
        save_model(tmp_path / "x.pt", model, "nope", settings, THRESHOLDS)


@pytest.mark.parametrize("fmt", ["torchscript", pytest.param("onnx", marks=pytest.mark.slow)])
def test_cli_exports_a_trained_model(tmp_path, capsys, fmt):
    tr, settings = _trained()
    ckpt = save_model(
        tmp_path / "model.pt", _perturbed(tr.model), "trainable", settings, THRESHOLDS
    )
    out = tmp_path / "out" / ("m.pt" if fmt == "torchscript" else "m.onnx")
    rc = cli_main(["export", "--model", str(ckpt), "--format", fmt, "--out", str(out)])
    report = json.loads(capsys.readouterr().out)
    assert rc == 0 and out.is_file()
    assert report["front"] == "trainable" and report["invalid_kept"] is True
    assert report["max_abs_diff_vs_eager"] <= 1e-5


def test_cli_export_model_refusals(tmp_path, capsys):
    tr, settings = _trained()
    ckpt = save_model(tmp_path / "model.pt", tr.model, "trainable", settings, THRESHOLDS)
    rc = cli_main(["export", "--model", str(ckpt), "--format", "torchscript", "--order", "30"])
    assert rc == 2 and "--order" in capsys.readouterr().err
    rc = cli_main(["export", "--model", str(tmp_path / "none.pt"), "--format", "torchscript"])
    assert rc == 2 and "no model checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "fpn_suppression.pt").exists()


def test_onnx_refuses_a_model_with_nlm_naming_it_and_writes_nothing(tmp_path, capsys):
    model = make_model("fixed+nlm", THRESHOLDS, Settings(layers=3, channels=4))
    with pytest.raises(ValueError, match="cannot export NonLocalMeans to ONNX.*TorchScript"):
        export_onnx(model, tmp_path / "m.onnx")
    ckpt = save_model(
        tmp_path / "model.pt", model, "fixed+nlm", Settings(layers=3, channels=4), THRESHOLDS
    )
    out = tmp_path / "m.onnx"
    rc = cli_main(["export", "--model", str(ckpt), "--format", "onnx", "--out", str(out)])
    assert rc != 0 and "NonLocalMeans" in capsys.readouterr().err
    assert not out.exists()
    rc = cli_main(
        ["export", "--model", str(ckpt), "--format", "torchscript", "--out", str(tmp_path / "m.pt")]
    )
    assert rc == 0 and (tmp_path / "m.pt").is_file()  # TorchScript takes it


# ------------------------------------------------ compile, autocast, CUDA


def test_training_step_under_torch_compile_matches_eager():
    torch.manual_seed(0)
    model = _perturbed(make_model("trainable", THRESHOLDS, Settings(layers=3, channels=4)))
    depth, amp = _frames()
    valid = torch.isfinite(depth) & (depth > 0)

    def loss_of(m):
        out = m(depth, amp)
        return torch.where(valid, out - 2.0, torch.zeros_like(out)).pow(2).mean()

    ref = loss_of(model)
    ref.backward()
    g_ref = model.front_end.filter.parametrizations.taps.original.grad.clone()
    model.zero_grad()
    compiled = torch.compile(model, backend="aot_eager")
    got = loss_of(compiled)
    got.backward()
    g = model.front_end.filter.parametrizations.taps.original.grad
    assert float(got) == pytest.approx(float(ref), rel=1e-5)
    assert torch.allclose(g, g_ref, rtol=1e-4, atol=1e-8)


def test_stage_under_inductor_matches_eager():
    stage = suppression_from_design(low=THRESHOLDS[0], high=THRESHOLDS[1], gate=False).eval()
    depth, amp = _frames()
    with torch.no_grad():
        ref = stage(depth, amp)
        got = torch.compile(stage)(depth, amp)
    assert float((got - ref).nan_to_num().abs().max()) <= 1e-5
    assert torch.isnan(got[0, 0, 3, 4]) and (got[1, 0, 5, 6:9] == 0).all()


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
def test_autocast_keeps_the_stage_in_float32_and_the_model_close(dtype):
    model = _perturbed(make_model("trainable", THRESHOLDS, Settings(layers=3, channels=8)))
    depth, amp = _frames()
    with torch.no_grad():
        ref_stage = model.front_end(depth, amp)
        ref = model(depth, amp)
        with torch.autocast("cpu", dtype=dtype):
            stage = model.front_end(depth, amp)
            out = model(depth, amp)
    assert stage.dtype == torch.float32
    assert torch.equal(stage.nan_to_num(), ref_stage.nan_to_num())  # not 8 bits of depth
    assert torch.isnan(out[0, 0, 3, 4]) and (out[1, 0, 5, 6:9] == 0).all()
    valid = torch.isfinite(depth) & (depth > 0)
    err = float((out.float() - ref)[valid].abs().max())
    assert err < 0.01  # the network's correction in half precision, not the depth itself


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_whole_model_on_cuda_matches_cpu():
    model = _perturbed(make_model("trainable", THRESHOLDS, Settings(layers=3, channels=8)))
    depth, amp = _frames()
    with torch.no_grad():
        ref = model(depth, amp)
        got = model.cuda()(depth.cuda(), amp.cuda()).cpu()
    assert float((got - ref).nan_to_num().abs().max()) <= 1e-4
    assert torch.isnan(got[0, 0, 3, 4]) and (got[1, 0, 5, 6:9] == 0).all()
