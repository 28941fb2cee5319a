"""The temporal filter (runtime/temporal.py): against a per-pixel NumPy loop written from its
description, TorchScript and ONNX equal to eager over a sequence with the state carried, the noise
factor on static pixels against the promise, a step restarts (no trail), persistence, invalid
pixels, bad inputs, dtype and device."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_fpn_torch.export import export_onnx
from tof_fpn_torch.runtime import (
    TemporalFilter,
    promised_noise_factor,
    temporal_filter,
    temporal_state,
)

SETTINGS = {"alpha": 0.3, "guard": 3.0, "sigma": 0.01, "noise_k": 0.0, "persistence": 2}


def ref_sequence(frames, amps, alpha, guard, sigma, noise_k, persistence):
    """Each pixel on its own, a Python loop over time: restart when there is no estimate or
    ``(d - m)^2 > g^2 s^2 (1 + v)``; else ``m += w (d - m)``, ``w = max(alpha, v / (1 + v))``,
    ``v = (1 - w)^2 v + w^2``; an invalid pixel shows its estimate for ``persistence`` frames."""
    t, h, w = frames.shape
    out = np.empty_like(frames)
    for y in range(h):
        for x in range(w):
            m, v, miss = 0.0, 0.0, 0
            for k in range(t):
                d = frames[k, y, x]
                a = None if amps is None else amps[k, y, x]
                ok = np.isfinite(d) and d > 0 and (a is None or (np.isfinite(a) and a >= 0))
                if not ok:
                    miss += 1
                    out[k, y, x] = m if (v > 0 and miss <= persistence) else d
                    continue
                miss = 0
                s2 = sigma**2 + ((noise_k / a) ** 2 if a is not None and noise_k > 0 else 0.0)
                if v == 0 or (d - m) ** 2 > guard**2 * s2 * (1 + v):
                    m, v = d, 1.0
                else:
                    g = max(alpha, v / (1 + v))
                    m, v = m + g * (d - m), (1 - g) ** 2 * v + g * g
                out[k, y, x] = m
    return out


def _recording(t=12, h=6, w=7, seed=0, dtype=torch.float64):
    """A noisy wall at 2 m with an object stepping in, holes (0, NaN, -1) and amplitudes."""
    g = torch.Generator().manual_seed(seed)
    d = 2.0 + 0.01 * torch.randn(t, 1, h, w, generator=g, dtype=dtype)
    d[t // 2 :, :, 1:4, 2:5] -= 0.8  # an object arrives
    d[3:6, :, 0, 0] = 0.0
    d[4, :, 5, 6] = float("nan")
    d[7:9, :, 2, 1] = -1.0
    d[2, :, 3, 3] = 0.0
    a = 50.0 + 100.0 * torch.rand(t, 1, h, w, generator=g, dtype=dtype)
    return d, a


def _run(f, frames, amps=None):
    state = temporal_state(frames[:1])
    outs = []
    for k in range(frames.shape[0]):
        a = None if amps is None else amps[k : k + 1]
        out, state = f(frames[k : k + 1], state, a)
        outs.append(out)
    return torch.cat(outs), state


@pytest.mark.parametrize("noise_k", [0.0, 0.5])
@pytest.mark.parametrize("persistence", [0, 2])
def test_matches_the_per_pixel_loop(noise_k, persistence):
    d, a = _recording()
    cfg = {**SETTINGS, "noise_k": noise_k, "persistence": persistence}
    for amps in (None, a) if noise_k == 0 else (a,):
        out, _ = _run(TemporalFilter(**cfg), d, amps)
        ref = ref_sequence(d[:, 0].numpy(), None if amps is None else amps[:, 0].numpy(), **cfg)
        np.testing.assert_allclose(out[:, 0].numpy(), ref, rtol=0, atol=1e-12, equal_nan=True)


def test_torchscript_equals_eager_over_a_sequence():
    d, a = _recording(dtype=torch.float32)
    f = TemporalFilter(**{**SETTINGS, "noise_k": 0.5})
    scripted = torch.jit.script(f)
    out_e, st_e = _run(f, d, a)
    out_s, st_s = _run(scripted, d, a)
    torch.testing.assert_close(out_s, out_e, rtol=0, atol=1e-5, equal_nan=True)
    torch.testing.assert_close(st_s, st_e, rtol=0, atol=1e-5)
    assert torch.equal(scripted.initial_state(d[:1]), f.initial_state(d[:1]))


def test_onnx_export_equals_eager_over_a_sequence(tmp_path):
    """export_onnx traces on its default (2, 1, 64, 80) inputs with dynamic shapes; the graph
    then runs a (1, 1, 16, 20) recording with the state fed back, equal to eager."""
    import onnx
    import onnxruntime as ort

    d, a = _recording(dtype=torch.float32, h=16, w=20)
    f = TemporalFilter(**{**SETTINGS, "noise_k": 0.5}).eval()
    path = export_onnx(f, tmp_path / "temporal.onnx")
    graph = onnx.load(str(path)).graph
    assert [i.name for i in graph.input] == ["depth", "state", "amplitude"]
    assert [o.name for o in graph.output] == ["output", "new_state"]
    sess = ort.InferenceSession(str(path))
    st = temporal_state(d[:1]).numpy()
    outs = []
    for k in range(d.shape[0]):
        feed = {"depth": d[k : k + 1].numpy(), "state": st, "amplitude": a[k : k + 1].numpy()}
        out, st = sess.run(None, feed)
        outs.append(out)
    out_e, st_e = _run(f, d, a)
    got = np.concatenate(outs)
    np.testing.assert_allclose(got, out_e.numpy(), rtol=0, atol=1e-5)
    np.testing.assert_allclose(st, st_e.numpy(), rtol=0, atol=1e-5)
    assert got[5, 0, 0, 0] == 0 and got[4, 0, 0, 0] > 1  # held for 2 frames, then invalid again


@pytest.mark.parametrize("alpha, guard", [(0.2, 3.0), (0.5, 2.5), (0.2, math.inf)])
def test_static_noise_falls_by_the_promised_factor(alpha, guard):
    """White noise on a static wall: the measured std ratio after the burn-in is the promise
    (the renewal computation, which includes the guard's false restarts) to 2 %, and the guard
    costs what the promise says against the plain EMA."""
    g = torch.Generator().manual_seed(1)
    shape, sd, burn, frames = (1, 1, 64, 64), 0.01, 60, 460
    state = temporal_state(torch.ones(shape, dtype=torch.float64))
    err = []
    for k in range(frames):
        d = 2.0 + sd * torch.randn(shape, generator=g, dtype=torch.float64)
        out, state = temporal_filter(d, state, alpha=alpha, guard=guard, sigma=sd)
        if k >= burn:
            err.append(out - 2.0)
    measured = float(torch.stack(err).pow(2).mean().sqrt()) / sd
    promised = promised_noise_factor(alpha, guard)
    assert measured == pytest.approx(promised, rel=0.02)
    if guard == math.inf:
        assert promised == pytest.approx(math.sqrt(alpha / (2 - alpha)), rel=1e-12)
    else:  # the false restarts cost something, measurably more than the plain EMA
        assert measured > 1.05 * math.sqrt(alpha / (2 - alpha))


def test_a_step_restarts_at_once_and_leaves_no_trail():
    """A 10 sd step: the output is the new depth on the first frame after it; without the guard
    the EMA trails for frames."""
    g = torch.Generator().manual_seed(2)
    sd = 0.01
    d = 2.0 + sd * torch.randn(30, 1, 8, 8, generator=g, dtype=torch.float64)
    d[15:] += 10 * sd
    out, _ = _run(TemporalFilter(alpha=0.2, guard=3.0, sigma=sd), d)
    assert torch.equal(out[15], d[15])  # restarted: the frame as it is
    after = (out[15:] - (2.0 + 10 * sd)).abs()
    assert float(after.max()) < 3.5 * sd  # within the noise from the first frame on
    plain, _ = _run(TemporalFilter(alpha=0.2, guard=math.inf, sigma=sd), d)
    assert float((plain[17] - (2.0 + 10 * sd)).abs().min()) > 3 * sd  # the EMA still trails


def test_amplitude_sets_the_guard():
    """With the noise law k / A a 4 cm step restarts a bright pixel (s = 5 mm) but not a dark
    one (s = 5 cm)."""
    d = torch.full((6, 1, 1, 2), 2.0, dtype=torch.float64)
    d[3:] += 0.04
    a = torch.tensor([100.0, 10.0], dtype=torch.float64).view(1, 1, 1, 2).expand(6, 1, 1, 2)
    out, _ = _run(TemporalFilter(alpha=0.2, sigma=0.0, noise_k=0.5), d, a)
    assert float(out[3, 0, 0, 0]) == pytest.approx(2.04)  # restarted
    assert float(out[3, 0, 0, 1]) < 2.02  # averaged in


def test_invalid_pixels_come_out_bit_for_bit_and_keep_the_estimate():
    d = torch.full((5, 1, 1, 3), 2.0, dtype=torch.float32)
    d[1:3, 0, 0, 0] = float("nan")
    d[1:3, 0, 0, 1] = 0.0
    d[1:3, 0, 0, 2] = -1.0
    before = d.clone()
    out, state = _run(TemporalFilter(persistence=0), d)
    assert torch.equal(d.view(torch.int32), before.view(torch.int32))  # inputs untouched
    assert torch.equal(out[1:3].view(torch.int32), d[1:3].view(torch.int32))  # NaN bits too
    assert (out[1:3, 0, 0, 1] == 0).all() and (out[1:3, 0, 0, 2] == -1).all()
    assert (out[3:] == 2.0).all()  # back: the estimate was kept through the gap
    assert float(state[0, 1, 0, 0]) < 0.5  # variance factor kept shrinking over 3 valid frames


def test_persistence_holds_the_last_estimate_for_p_frames():
    d = torch.full((8, 1, 1, 1), 2.0, dtype=torch.float64)
    d[2:7] = 0.0
    out, _ = _run(TemporalFilter(persistence=3), d)
    assert out[2:5].flatten().tolist() == [2.0, 2.0, 2.0]
    assert out[5:7].flatten().tolist() == [0.0, 0.0]  # held no longer than 3 frames
    assert float(out[7]) == 2.0
    first, _ = _run(TemporalFilter(persistence=3), torch.zeros(2, 1, 1, 1))
    assert (first == 0).all()  # nothing to hold before the first valid frame


def test_bad_inputs_say_what_is_wrong():
    d = torch.ones(1, 1, 4, 4)
    s = temporal_state(d)
    with pytest.raises(ValueError, match="alpha"):
        TemporalFilter(alpha=0.0)
    with pytest.raises(ValueError, match="guard"):
        TemporalFilter(guard=-1.0)
    with pytest.raises(ValueError, match="noise level"):
        TemporalFilter(sigma=0.0, noise_k=0.0)
    with pytest.raises(ValueError, match="persistence"):
        TemporalFilter(persistence=-1)
    with pytest.raises(ValueError, match="state must have shape"):
        temporal_filter(d, torch.zeros(1, 1, 4, 4))
    with pytest.raises(ValueError, match="dtype and device"):
        temporal_filter(d, s.double())
    with pytest.raises(ValueError, match="amplitude"):
        temporal_filter(d, s, torch.ones(1, 1, 4, 5))
    with pytest.raises(ValueError, match="4 dimensions"):
        temporal_filter(d[0], s)
    with pytest.raises(TypeError, match="torch.from_numpy"):
        temporal_filter(np.ones((1, 1, 4, 4)), s)


DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_device_and_dtype_follow_the_input(device, dtype):
    d = torch.full((2, 3, 4, 5), 1.5, dtype=dtype, device=device)
    f = TemporalFilter()
    out, state = f(d, f.initial_state(d))
    assert out.dtype == dtype and out.device == d.device and out.shape == d.shape
    assert state.dtype == dtype and state.device == d.device and state.shape == (2, 9, 4, 5)
