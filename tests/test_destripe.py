"""destripe / Destripe: against a NumPy/SciPy reference, recovery, never hurts, the real ADI wall,
invalid pixels, TorchScript, complex domain, errors."""

from __future__ import annotations

import math

import _destripe_ref as R
import numpy as np
import pytest
import torch
from conftest import REAL_DATA_DIR

from tof_fpn_torch import constants as K
from tof_fpn_torch.analysis.metrics import psnr
from tof_fpn_torch.analysis.stripe_energy import (
    column_stripe_energy,
    lowpass_change,
    structure_mask,
)
from tof_fpn_torch.runtime import Destripe, destripe
from tof_fpn_torch.runtime import _destripe_core as core
from tof_fpn_torch.runtime._destripe_core import column_offsets, highpass
from tof_fpn_torch.sim import (
    Camera,
    ReadoutFPN,
    Simulation,
    add_depth_noise,
    default_terms,
    planar_scene,
    synthetic_scene,
)

F0 = K.CAMCUBE_MODULATION_FREQUENCY_HZ
SCALE = K.SPEED_OF_LIGHT_AIR / (4 * math.pi * F0)  # metres per radian of phase


def _edges_scene(h=60, w=120, seed=0, stripes=0.01, noise=0.003):
    """Depth with vertical step edges (full and partial height), a ramp, column offsets, noise."""
    g = torch.Generator().manual_seed(seed)
    xx = torch.arange(w, dtype=torch.float64).expand(h, w)
    yy = torch.arange(h, dtype=torch.float64)[:, None].expand(h, w)
    scene = 2.0 + 0.004 * xx + 0.002 * yy
    scene = scene + 0.6 * (xx >= 70)  # a full-height wall-to-box edge
    scene = scene - 0.4 * ((xx >= 20) & (xx < 35) & (yy < 25))  # a partial-height box
    scene = scene + 0.2 * ((xx == 90) & (yy > 30))  # a thin bar, lower half only
    offsets = stripes * torch.randn(w, generator=g, dtype=torch.float64)
    depth = scene + offsets + noise * torch.randn(h, w, generator=g, dtype=torch.float64)
    return depth[None, None], scene[None, None], offsets


# --- the estimator against the independent NumPy / SciPy reference ---------------------------


@pytest.mark.parametrize("shrink", ["none", "global", "local"])
@pytest.mark.parametrize("masked", [False, True])
def test_offsets_match_numpy_reference(shrink, masked):
    depth, _, _ = _edges_scene(36, 80, seed=1)
    x = torch.cat([depth, depth.flip(-1) + 0.01], 0)
    valid = None
    if masked:
        valid = torch.ones_like(x, dtype=torch.bool)
        valid[0, 0, 3, 7] = False
        valid[1, 0, 10:14, 30] = False
    off, _ = column_offsets(x, valid, 31, 3.0, shrink, 64, 16)
    for n in range(2):
        v = None if valid is None else valid[n, 0].numpy()
        ref = R.column_offsets(
            x[n].numpy(),
            v,
            31,
            3.0,
            shrink,
            64,
            16,
            K.DESTRIPE_STEP_CLIP,
            core.NULL_Z,
            core.MAX_EDGE_SHARE,
        )
        np.testing.assert_allclose(off[n].numpy(), ref, rtol=0, atol=1e-12)


def test_complex_offsets_match_numpy_reference():
    depth, _, _ = _edges_scene(30, 70, seed=2)
    z = torch.cat([depth, 0.5 * depth.flip(-1)], 1)  # (1, 2, H, W): two channels, one test
    off, _ = column_offsets(z, None, 31, 3.0, "local", 64, 16)
    ref = R.column_offsets(
        z[0].numpy(),
        None,
        31,
        3.0,
        "local",
        64,
        16,
        K.DESTRIPE_STEP_CLIP,
        core.NULL_Z,
        core.MAX_EDGE_SHARE,
    )
    np.testing.assert_allclose(off[0].numpy(), ref, rtol=0, atol=1e-12)


def test_fast_path_equals_masked_path():
    """All valid: the mask-free (hardshrink) path gives the masked path's offsets."""
    depth, _, _ = _edges_scene(64, 100, seed=3)
    ones = torch.ones_like(depth, dtype=torch.bool)
    a, _ = column_offsets(depth, None, 31, 3.0, "local", 128, 32)
    b, _ = column_offsets(depth, ones, 31, 3.0, "local", 128, 32)
    torch.testing.assert_close(a, b, rtol=0, atol=1e-12)
    a32, _ = column_offsets(depth.float(), None, 31, 3.0, "local", 128, 32)
    torch.testing.assert_close(a32.double(), b, rtol=0, atol=2e-5)


def test_highpass_removes_lines_exactly_and_matches_polyfit():
    g = torch.Generator().manual_seed(0)
    line = 3.0 + 0.25 * torch.arange(50, dtype=torch.float64)[None, None]
    assert float(highpass(line, 31).abs().max()) < 1e-10
    p = torch.randn(1, 1, 50, generator=g, dtype=torch.float64)
    np.testing.assert_allclose(highpass(p, 11)[0].numpy(), R.highpass(p[0].numpy(), 11), atol=1e-12)


# --- what it does -----------------------------------------------------------------------------


def test_recovers_injected_column_offsets_next_to_vertical_edges():
    depth, scene, offsets = _edges_scene(120, 160, seed=4, stripes=0.01, noise=0.003)
    out = destripe(depth)
    est = (depth - out)[0, 0].mean(0)  # the subtracted per-column offsets
    truth = highpass(offsets[None, None], K.DESTRIPE_WIDTH)[0, 0]
    r = np.corrcoef(est.numpy(), truth.numpy())[0, 1]
    assert r > 0.95, r
    # the stripes left after the correction, seen by the stripe energy: >= 10 dB less
    e0 = column_stripe_energy(depth - scene + 2.0, width=9).covariance
    e1 = column_stripe_energy(out - scene + 2.0, width=9).covariance
    assert float(e1) < 0.1 * float(e0)
    # the edges are not taken for stripes: the full-height edge at x = 70 is kept to within 3 mm
    step_in = float((depth - offsets)[0, 0, :, 70].mean() - (depth - offsets)[0, 0, :, 69].mean())
    step_out = float(out[0, 0, :, 70].mean() - out[0, 0, :, 69].mean())
    assert abs(step_out - step_in) < 0.003 + 2 * float(offsets.abs().max())
    assert abs(step_out - 0.6 - 0.004) < 0.03


@pytest.mark.parametrize("size", [32, 47, 64, 101, 128])
@pytest.mark.parametrize("kind", ["synthetic", "planar"])
def test_never_hurts_on_stripe_free_scenes(size, kind):
    make = synthetic_scene if kind == "synthetic" else planar_scene
    scene = make(size, size + 5, seed=size)
    for lam in (1.0, 100.0):
        g = torch.Generator().manual_seed(size)
        noisy = add_depth_noise(
            scene.depth, scene.amplitude, lam, amplitude_floor=10.0, generator=g
        )
        for dim in (-1, -2):
            out = destripe(noisy, dim=dim)
            change = float(psnr(out, scene.depth) - psnr(noisy, scene.depth))
            assert abs(change) < 0.1, (lam, dim, change)
            mean_change = float((out.double().mean() - noisy.double().mean()) / noisy.mean())
            assert abs(mean_change) < 5e-4, (lam, dim, mean_change)


def _adi_depth() -> torch.Tensor:
    path = REAL_DATA_DIR / "adi_adtf3175" / "wall_depth_u16le_512x512.bin"
    assert path.is_file(), f"the real ADI capture is missing: {path}"
    raw = np.fromfile(path, dtype="<u2").reshape(512, 512).astype(np.float64)
    return torch.from_numpy(raw)[None, None]


def test_real_adi_wall_column_stripe_energy_falls_10_db():
    depth = _adi_depth()
    region = structure_mask(depth, 4.0, width=15, dilate=6)  # away from the curved cable
    region[..., 416:, :] = False  # the clutter at the bottom
    region[..., :8] = False
    region[..., -8:] = False
    e0 = float(column_stripe_energy(depth, region, width=9, split=208).covariance)
    assert e0 > 0.03  # the capture's stripes (top and bottom halves correlate ~0.95)
    out = destripe(depth)
    e1 = float(column_stripe_energy(out, region, width=9, split=208).covariance)
    assert e1 < e0 / 10, (e0, e1)
    assert float(lowpass_change(depth, out, 15)) < 0.5  # mm: the low-pass depth does not move
    invalid = depth <= 0
    assert int(invalid.sum()) > 0 and torch.equal(out[invalid], depth[invalid])


# --- invalid pixels, shapes, dtypes, TorchScript -----------------------------------------------


def _holes(depth, amplitude):
    d, a = depth.clone(), amplitude.clone()
    d[0, 0, 2, 3] = float("nan")
    d[0, 0, 5, 6:9] = 0.0
    d[-1, 0, 7, 1] = -1.0
    d[-1, 0, 8, 2] = float("inf")
    a[0, 0, 9, 9] = float("nan")
    a[-1, 0, 10, 4] = -5.0
    return d, a


@pytest.mark.parametrize("domain", ["depth", "complex"])
@pytest.mark.parametrize("dim", [-1, -2, (-2, -1)])
def test_invalid_pixels_are_returned_bit_identical(domain, dim):
    depth, _, _ = _edges_scene(40, 64, seed=5)
    depth = torch.cat([depth, depth + 0.1], 0)
    amp = torch.full_like(depth, 80.0)
    d, a = _holes(depth, amp)
    kw = {"domain": domain, "dim": dim}
    if domain == "complex":
        kw["modulation_frequency_hz"] = F0
    out = destripe(d, a, **kw)
    bad = ~((d > 0) & torch.isfinite(d) & (a >= 0) & torch.isfinite(a))
    assert int(bad.sum()) == 8
    assert torch.equal(out[bad].nan_to_num(nan=123.0), d[bad].nan_to_num(nan=123.0))
    assert bool(torch.isfinite(out[~bad]).all())
    d0 = d.clone()
    destripe(d, a, **kw)
    assert torch.equal(d.nan_to_num(nan=1.0), d0.nan_to_num(nan=1.0))  # input not modified


@pytest.mark.parametrize(
    "shape", [(0, 1, 8, 8), (1, 1, 1, 9), (1, 1, 9, 1), (1, 1, 2, 2), (2, 3, 5, 9), (1, 1, 3, 64)]
)
def test_tiny_empty_and_odd_shapes(shape):
    g = torch.Generator().manual_seed(0)
    x = 1.0 + torch.rand(shape, generator=g)
    for dim in (-1, -2, (-2, -1)):
        out = destripe(x, dim=dim)
        assert out.shape == x.shape and out.dtype == x.dtype
        assert bool(torch.isfinite(out).all())
    if x.shape[-2] < 2 or x.shape[-1] < 2:
        assert torch.equal(destripe(x), x)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float32, torch.float64])
def test_dtype_follows_input(dtype):
    depth, _, _ = _edges_scene(32, 48, seed=6)
    out = destripe(depth.to(dtype))
    assert out.dtype == dtype
    ref = destripe(depth.float())
    tol = 1e-2 if dtype in (torch.float16, torch.bfloat16) else 1e-5
    torch.testing.assert_close(out.float(), ref, rtol=0, atol=tol * 3)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_matches_cpu():
    depth, _, _ = _edges_scene(64, 96, seed=7)
    torch.testing.assert_close(destripe(depth.cuda()).cpu(), destripe(depth), rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"dim": (-2, -1), "shrink": "global"},
        {"domain": "complex", "modulation_frequency_hz": F0},
        {"domain": "complex", "modulation_frequency_hz": F0, "wrap": False, "shrink": "none"},
    ],
)
def test_torchscript_matches_eager(kw):
    m = Destripe(**kw)
    scripted = torch.jit.script(m)
    depth, _, _ = _edges_scene(40, 72, seed=8)
    depth = torch.cat([depth, depth + 0.5], 0)
    amp = torch.full_like(depth, 60.0)
    for d, a in ((depth, amp), _holes(depth, amp)):
        torch.testing.assert_close(scripted(d, a), m(d, a), rtol=0, atol=0, equal_nan=True)
    if "domain" not in kw:
        torch.testing.assert_close(scripted(depth), destripe(depth, **kw), rtol=0, atol=0)


# --- the complex domain --------------------------------------------------------------------------


def _complex_striped(depth, amp, seed=0, level=3.0):
    g = torch.Generator().manual_seed(seed)
    w = depth.shape[-1]
    c = level * torch.randn(2, w, generator=g, dtype=torch.float64)
    z = amp * torch.exp(1j * depth / SCALE) + (c[0] + 1j * c[1])
    z = z + 0.3 * torch.randn(z.shape, generator=g, dtype=torch.complex128)
    d = torch.remainder(torch.angle(z), 2 * math.pi) * SCALE
    return d, z.abs(), c


def test_complex_domain_is_wrap_safe():
    """A scene right at the wrap (depth near 0 and near c_L / 2f): offsets are removed in z and
    the output is wrapped like single-frequency depth; wrap=False keeps the input's branch."""
    h, w = 64, 96
    rng = 2 * math.pi * SCALE
    xx = torch.arange(w, dtype=torch.float64).expand(h, w)
    truth = torch.remainder(0.05 - 0.002 * xx, rng)[None, None]  # crosses 0 -> ~7.49 m
    amp = torch.full_like(truth, 40.0)
    d, a, _ = _complex_striped(truth, amp, seed=1)
    out = destripe(d, a, domain="complex", modulation_frequency_hz=F0)
    assert bool(((out >= 0) & (out < rng)).all())

    def err(x):  # error modulo the range
        return torch.remainder(x - truth + rng / 2, rng) - rng / 2

    assert float(err(out).pow(2).mean().sqrt()) < 0.5 * float(err(d).pow(2).mean().sqrt())
    unwrapped = d + rng  # e.g. a multi-frequency camera's depth on the second branch
    out2 = destripe(unwrapped, a, domain="complex", modulation_frequency_hz=F0, wrap=False)
    assert float((out2 - unwrapped).abs().max()) < 1.0
    torch.testing.assert_close(torch.remainder(out2, rng), out, rtol=0, atol=1e-9)


def test_complex_beats_depth_domain_on_raw_simulator():
    """Broadband read-out offsets of the raw simulator, low light: the complex-domain correction
    recovers >= 3 dB, the depth-domain one (whose column-constant model does not hold: the depth
    error of a z offset scales with 1/A and the phase) much less."""
    scene = planar_scene(128, 128, seed=2)
    fpn = ReadoutFPN(offset_amplitudes=(0.0, 0.0), gain_amplitudes=(0.0, 0.0), random_offset=100.0)
    terms = default_terms()
    terms[2] = fpn
    cam = Camera(integration_time=1e-3, illumination_power=0.1, ambient_irradiance=0.02)
    res = Simulation(cam, terms).run(scene, seed=0)
    d, a = res.depth, res.amplitude
    p0 = float(psnr(d, scene.depth))
    pc = float(psnr(destripe(d, a, domain="complex", modulation_frequency_hz=F0), scene.depth))
    pd = float(psnr(destripe(d, a), scene.depth))
    assert pc - p0 > 3.0, (p0, pc)
    assert pc > pd + 2.0, (pd, pc)
    assert pd > p0 - 0.1


def test_complex_domain_leaves_a_vertical_amplitude_texture_alone():
    """A flat wall with a painted vertical pattern (amplitude only, the same in every row): the
    estimator sees column offsets in z along the wall's phase; the coherence projection drops
    them, so the depth does not move (without it the wall's columns get phase errors)."""
    g = torch.Generator().manual_seed(3)
    h, w = 96, 128
    xx = torch.arange(w, dtype=torch.float64)
    amp = (60.0 * (1.0 + 0.3 * torch.cos(2 * math.pi * xx / 9.0))).expand(h, w)[None, None]
    wall = torch.full_like(amp, 3.0)
    z = amp * torch.exp(1j * wall / SCALE)
    z = z + 0.5 * torch.randn(z.shape, generator=g, dtype=torch.complex128)
    d = torch.remainder(torch.angle(z), 2 * math.pi) * SCALE
    out = destripe(d, z.abs(), domain="complex", modulation_frequency_hz=F0)
    moved = float((out - d).pow(2).mean().sqrt())
    noise = float((d - wall).pow(2).mean().sqrt())
    assert moved < 0.05 * noise, (moved, noise)


# --- errors --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"width": 2}, r"width must be an int >= 3.*got 2"),
        ({"width": 31.0}, r"width must be an int >= 3.*got 31.0"),
        ({"clip": 0.0}, r"clip must be a finite number > 0.*got 0.0"),
        ({"clip": math.inf}, r"clip must be a finite number > 0.*got inf"),
        ({"shrink": "soft"}, r"shrink must be one of \('global', 'local', 'none'\), got 'soft'"),
        ({"domain": "phase"}, r"domain must be one of \('depth', 'complex'\), got 'phase'"),
        ({"domain": "complex"}, r"modulation_frequency_hz must be a finite number > 0.*got None"),
        ({"modulation_frequency_hz": 2e7}, r"used only with domain='complex', got 20000000.0"),
        ({"dim": 0}, r"dim must be -1 \(width\), -2 \(height\) or \(-2, -1\).*got 0"),
        ({"local_width": 1}, r"local_width must be an int >= 3.*got 1"),
    ],
)
def test_errors_name_argument_value_and_allowed(kw, match):
    x = torch.rand(1, 1, 8, 8) + 1.0
    with pytest.raises(ValueError, match=match):
        destripe(x, torch.ones_like(x), **kw)
    if "dim" not in kw:
        with pytest.raises(ValueError, match=match):
            Destripe(**kw)


def test_input_errors():
    x = torch.rand(1, 1, 8, 8) + 1.0
    with pytest.raises(ValueError, match=r"depth must have shape \(B, C, H, W\).*got 3"):
        destripe(x[0])
    with pytest.raises(ValueError, match="depth must be a floating-point tensor.*torch.int64"):
        destripe(x.long())
    with pytest.raises(ValueError, match=r"amplitude and depth must have the same shape"):
        destripe(x, torch.ones(1, 1, 8, 9))
    with pytest.raises(ValueError, match="amplitude is required with domain='complex'"):
        destripe(x, domain="complex", modulation_frequency_hz=F0)
    with pytest.raises(ValueError, match="amplitude is required with domain='complex'"):
        Destripe(domain="complex", modulation_frequency_hz=F0)(x)


def test_a_valid_pixel_never_comes_out_invalid():
    """Offsets of -15 mm on every other column of a 20 mm-deep flat scene, and one row only
    0.1 mm deep: there the correction (+7.5 mm on the odd columns) would give <= 0, so the input is
    kept (the package's rule), in both domains. This also checks that a periodic pattern at pi
    (bimodal column steps) is not taken for edges."""
    g = torch.Generator().manual_seed(9)
    h, w = 48, 64
    offsets = torch.where(torch.arange(w) % 2 == 0, -0.015, 0.0).double()
    depth = 0.02 + offsets + 0.0005 * torch.randn(h, w, generator=g, dtype=torch.float64)
    depth[20, 1::2] = 1e-4
    depth = depth[None, None]
    # (with wrap=True the complex domain wraps such a pixel to ~7.49 m instead, as the camera)
    for kw in ({}, {"domain": "complex", "modulation_frequency_hz": F0, "wrap": False}):
        out = destripe(depth, torch.full_like(depth, 50.0), **kw)
        assert bool(((out > 0) & torch.isfinite(out)).all())
        assert torch.equal(out[0, 0, 20, 1::2], depth[0, 0, 20, 1::2])
        assert float((out - depth)[0, 0, 5, 1::2].mean()) < -0.005  # elsewhere: corrected
