"""Property tests (hypothesis, seeded) of every run-time stage and of NLM.

Over shapes (odd, even, 1 pixel, empty batch B = 0, H or W of 1), dtypes (float32, float64,
float16, bfloat16) and special values (NaN of both signs, +-inf, +-0, negative) placed in depth
and in amplitude, for ``fpn_filter``, ``FPNFilter``, ``amplitude_fusion``, ``FPNSuppression``
(``suppression_from_design``) and ``non_local_means``:

(a) every invalid pixel (``valid_mask(depth, amplitude)``) is returned bit-identical (NaN stays
    NaN, -0 stays -0);
(b) no valid pixel becomes NaN or inf;
(c) a constant scene (every valid pixel the same positive depth) is returned unchanged to 1e-6
    relative, holes or not.

(c) holds for a filter with unit DC gain (the default design constrains H(0) = 1; the paper's
unconstrained one has ``H(0) = 0.967``) and for the default stage ``suppression_from_design()``.
"""

from __future__ import annotations

import functools
import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tof_fpn_torch import FPNFilter, design_fpn, fpn_filter
from tof_fpn_torch.build import suppression_from_design
from tof_fpn_torch.denoise import non_local_means
from tof_fpn_torch.runtime import amplitude_fusion, valid_mask

DTYPES = (torch.float32, torch.float64, torch.float16, torch.bfloat16)
BITS = {
    torch.float16: torch.int16,
    torch.bfloat16: torch.int16,
    torch.float32: torch.int32,
    torch.float64: torch.int64,
}
DEPTH_SPECIALS = (math.nan, -math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, -1e-3)
AMPLITUDE_SPECIALS = (math.nan, -math.nan, math.inf, -math.inf, -1.0, -0.0, 0.0)
DIMS = (-1, -2, (-2, -1))
BORDERS = ("reflect", "replicate", "circular", "zeros")
CONSTANT_BORDERS = ("reflect", "replicate", "circular")  # zero padding is not a constant scene


@functools.cache
def _taps(order: int) -> torch.Tensor:
    """The paper's unconstrained design of ``order`` (both parities) with rho = 0.14."""
    return torch.from_numpy(design_fpn(order, 0.14, unit_dc=False).taps)


@functools.cache
def _unit_dc_filter(order: int, dim, border: str) -> FPNFilter:
    taps = torch.from_numpy(design_fpn(order, 0.14).taps)  # unit DC gain by construction
    assert abs(float(taps.sum()) - 1.0) < 1e-12
    return FPNFilter(taps, dim=dim, border=border, allow_shift=True)


@functools.cache
def _stage(dim, adaptive: bool):
    return suppression_from_design(dim=dim, adaptive=adaptive)


# ----------------------------------------------------------------------------- inputs

sizes = st.one_of(st.just(1), st.integers(1, 9), st.integers(10, 48))


@st.composite
def images(draw, channels=None, constant=False):
    """``(depth, amplitude)`` of one dtype: a positive scene (or a constant one) with special
    values at drawn pixels of depth and of amplitude, sometimes a whole invalid row or column."""
    b = draw(st.sampled_from((0, 1, 1, 2)))
    c = channels or draw(st.sampled_from((1, 1, 2)))
    h, w = draw(sizes), draw(sizes)
    dtype = draw(st.sampled_from(DTYPES))
    g = torch.Generator().manual_seed(draw(st.integers(0, 2**31 - 1)))
    shape = (b, c, h, w)
    if constant:
        value = draw(st.sampled_from((0.37, 1.0, 2.5, 7.49, 123.0)))
        depth = torch.full(shape, value, dtype=torch.float64)
    else:
        depth = 0.2 + 7.0 * torch.rand(shape, generator=g, dtype=torch.float64)
    amplitude = 1000.0 * torch.rand((b, 1, h, w), generator=g, dtype=torch.float64)
    n = depth.numel()
    if n:
        flat = depth.view(-1)
        for _ in range(draw(st.integers(0, 6))):
            flat[draw(st.integers(0, n - 1))] = draw(st.sampled_from(DEPTH_SPECIALS))
        if draw(st.booleans()):  # a whole row or column without measurements
            where = draw(st.integers(0, 10**6))
            if draw(st.booleans()):
                depth[..., where % h, :] = draw(st.sampled_from(DEPTH_SPECIALS))
            else:
                depth[..., where % w] = draw(st.sampled_from(DEPTH_SPECIALS))
        flat_a = amplitude.view(-1)
        for _ in range(draw(st.integers(0, 4))):
            flat_a[draw(st.integers(0, flat_a.numel() - 1))] = draw(
                st.sampled_from(AMPLITUDE_SPECIALS)
            )
    return depth.to(dtype), amplitude.to(dtype)


def _check_invalid_kept_valid_finite(out, depth, invalid):
    """(a) and (b): ``out`` equals ``depth`` bit for bit at ``invalid`` (NaN: still NaN), and
    is finite everywhere else."""
    assert out.shape == depth.shape and out.dtype == depth.dtype
    was, now = depth[invalid], out[invalid]
    nan = torch.isnan(was)
    assert bool(torch.isnan(now[nan]).all()), "a NaN pixel came out as a number"
    bits = BITS[depth.dtype]
    assert torch.equal(now[~nan].view(bits), was[~nan].view(bits)), "an invalid pixel changed"
    assert bool(torch.isfinite(out[~invalid]).all()), "a valid pixel became NaN/inf"


def _check_constant(out, depth, valid, value):
    """(c): every valid output equals the constant to 1e-6 relative."""
    got = out[valid].double()
    err = float((got - value).abs().max()) / value if got.numel() else 0.0
    assert err <= 1e-6, f"constant scene {value} changed by {err:.3g} (relative)"


# ----------------------------------------------------------------------------- FPN filter


@settings(deadline=None, max_examples=100)
@given(
    data=images(),
    order=st.sampled_from((20, 21)),
    dim=st.sampled_from(DIMS),
    border=st.sampled_from(BORDERS),
    use_mask=st.booleans(),
    seed=st.integers(0, 1000),
)
def test_fpn_filter_and_module_keep_invalid_pixels(data, order, dim, border, use_mask, seed):
    depth, _ = data
    mask = None
    if use_mask:  # the caller's extra "invalid" marks
        g = torch.Generator().manual_seed(seed)
        mask = torch.rand(depth.shape, generator=g) > 0.2
    invalid = ~valid_mask(depth, mask=mask)
    taps = _taps(order)
    out_fn = fpn_filter(depth, taps, dim=dim, border=border, mask=mask)
    out_mod = FPNFilter(taps, dim=dim, border=border, allow_shift=True)(depth, mask)
    for out in (out_fn, out_mod):
        _check_invalid_kept_valid_finite(out, depth, invalid)
    torch.testing.assert_close(out_fn, out_mod, rtol=0, atol=0, equal_nan=True)


@settings(deadline=None, max_examples=100)
@given(
    data=images(constant=True),
    order=st.sampled_from((20, 21)),
    dim=st.sampled_from(DIMS),
    border=st.sampled_from(CONSTANT_BORDERS),
)
def test_unit_dc_filter_returns_a_constant_scene_unchanged(data, order, dim, border):
    depth, _ = data
    valid = valid_mask(depth)
    value = float(depth[valid][0]) if bool(valid.any()) else 1.0
    f = _unit_dc_filter(order, dim, border)
    out = f(depth)
    _check_invalid_kept_valid_finite(out, depth, ~valid)
    _check_constant(out, depth, valid, value)
    # the functional form with the same taps agrees
    torch.testing.assert_close(fpn_filter(depth, f.taps, dim, border), out, equal_nan=True)


# ----------------------------------------------------------------------------- fusion


@settings(deadline=None, max_examples=100)
@given(data=images(channels=1), constant=st.booleans(), seed=st.integers(0, 1000))
def test_amplitude_fusion_keeps_invalid_pixels_and_constants(data, constant, seed):
    depth, amplitude = data
    valid = valid_mask(depth, amplitude)
    g = torch.Generator().manual_seed(seed)
    noise = 0.05 * torch.randn(depth.shape, generator=g, dtype=torch.float64).to(depth.dtype)
    filtered = depth.clone() if constant else depth + noise
    # what the filtered map holds at invalid pixels must not leak out
    filtered = torch.where(valid, filtered, torch.full_like(filtered, math.nan))
    out = amplitude_fusion(filtered, depth, amplitude)
    _check_invalid_kept_valid_finite(out, depth, ~valid)
    if constant:  # D_F = D: eq. (11) gives D whatever the amplitude
        assert torch.equal(out[valid], depth[valid])


# ----------------------------------------------------------------------------- suppression


@settings(deadline=None, max_examples=100)
@given(data=images(channels=1), dim=st.sampled_from(DIMS), adaptive=st.booleans())
def test_suppression_keeps_invalid_pixels(data, dim, adaptive):
    depth, amplitude = data
    out = _stage(dim, adaptive)(depth, amplitude)
    _check_invalid_kept_valid_finite(out, depth, ~valid_mask(depth, amplitude))


@settings(deadline=None, max_examples=60)
@given(data=images(channels=1, constant=True), dim=st.sampled_from(DIMS), adaptive=st.booleans())
def test_default_suppression_returns_a_constant_scene_unchanged(data, dim, adaptive):
    """The default stage: unit DC gain and the stripe gate (with the paper's unconstrained design,
    H(0) = 0.967, a flat wall came out 3.3 % closer)."""
    depth, amplitude = data
    valid = valid_mask(depth, amplitude)
    value = float(depth[valid][0]) if bool(valid.any()) else 1.0
    out = _stage(dim, adaptive)(depth, amplitude)
    _check_invalid_kept_valid_finite(out, depth, ~valid)
    _check_constant(out, depth, valid, value)


@settings(deadline=None, max_examples=60)
@given(data=images(channels=1, constant=True), dim=st.sampled_from(DIMS), adaptive=st.booleans())
def test_unit_dc_suppression_returns_a_constant_scene_unchanged(data, dim, adaptive):
    """The notch and fusion themselves, without the gate that would leave the scene alone."""
    from tof_fpn_torch import constants as K
    from tof_fpn_torch.runtime import AmplitudeFusion, FPNSuppression

    depth, amplitude = data
    valid = valid_mask(depth, amplitude)
    value = float(depth[valid][0]) if bool(valid.any()) else 1.0
    taps = torch.from_numpy(design_fpn(20, 0.14).taps)
    notch = FPNFilter(taps, dim=dim, notches=K.DEFAULT_NOTCHES)
    stage = FPNSuppression(notch, AmplitudeFusion() if adaptive else None, gate=False)
    out = stage(depth, amplitude)
    _check_invalid_kept_valid_finite(out, depth, ~valid)
    _check_constant(out, depth, valid, value)


# ----------------------------------------------------------------------------- NLM

nlm_params = st.fixed_dictionaries(
    {
        "patch_size": st.sampled_from((1, 3, 5)),
        "patch_distance": st.integers(0, 3),
        "kernel": st.sampled_from(("box", "gaussian")),
    }
)


@settings(deadline=None, max_examples=100)
@given(
    data=images(),
    params=nlm_params,
    noise=st.sampled_from(("sigma", "sigma-map", "amplitude-k")),
    constant=st.booleans(),
)
def test_nlm_keeps_invalid_pixels_and_constants(data, params, noise, constant):
    """Noise level given (scalar, per-pixel map, or ``k / A``); the estimated one: next test."""
    depth, amplitude = data
    if constant:
        depth = torch.where(valid_mask(depth), torch.full_like(depth, 2.5), depth)
    kwargs = {
        "sigma": {"sigma": 0.05},
        "sigma-map": {"sigma": torch.full_like(amplitude, 0.05)},
        "amplitude-k": {"amplitude": amplitude, "k": 3.0},
    }[noise]
    invalid = ~valid_mask(depth).all(1, keepdim=True).expand_as(depth)
    if noise == "amplitude-k":
        invalid = invalid | ~valid_mask(depth, amplitude)
    out = non_local_means(depth, **kwargs, **params)
    _check_invalid_kept_valid_finite(out, depth, invalid)
    if constant:
        _check_constant(out, depth, ~invalid, 2.5)


@settings(deadline=None, max_examples=60)
@given(data=images(), params=nlm_params, with_amplitude=st.booleans())
def test_nlm_with_estimated_noise_level_any_shape(data, params, with_amplitude):
    """sigma (wavelet MAD) or k (of sigma = k / A) estimated from the image itself: the image can
    be as small as 1 x 1 (``non_local_means`` accepts H, W >= 1)."""
    depth, amplitude = data
    kwargs = {"amplitude": amplitude} if with_amplitude else {}
    invalid = ~valid_mask(depth).all(1, keepdim=True).expand_as(depth)
    if with_amplitude:
        invalid = invalid | ~valid_mask(depth, amplitude)
    out = non_local_means(depth, **kwargs, **params)
    _check_invalid_kept_valid_finite(out, depth, invalid)


def test_strategies_reach_the_cases_they_are_meant_to():
    """The inputs above do contain what the properties are about (else they prove nothing)."""
    seen = set()

    @settings(deadline=None, max_examples=200)
    @given(data=images())
    def collect(data):
        depth, amplitude = data
        b, _, h, w = depth.shape
        seen.add(("dtype", depth.dtype))
        seen.update({("B=0",) if b == 0 else ("B>0",), ("H=1",) if h == 1 else ("H>1",)})
        seen.add(("W=1",) if w == 1 else ("W>1",))
        seen.add(("odd",) if h % 2 else ("even",))
        if depth.numel():
            seen.add(("nan-depth",) if bool(torch.isnan(depth).any()) else ("no-nan",))
            seen.add(("-inf-depth",) if bool((depth == -math.inf).any()) else ("no-inf",))
            seen.add(("bad-amplitude",) if bool((~valid_mask(amplitude)).any()) else ("ok",))
            seen.add(("all-valid",) if bool(valid_mask(depth, amplitude).all()) else ("holes",))

    collect()
    want = {("dtype", t) for t in DTYPES} | {
        ("B=0",),
        ("H=1",),
        ("W=1",),
        ("odd",),
        ("even",),
        ("nan-depth",),
        ("-inf-depth",),
        ("bad-amplitude",),
        ("all-valid",),
        ("holes",),
    }
    assert want <= seen, want - seen


@pytest.mark.parametrize("dtype", DTYPES)
def test_signed_codes_survive_every_stage(dtype):
    """-0, -inf, -1 and NaN at invalid pixels, every dtype, every stage (a fixed example of (a)):
    the numbers keep their bits, sign included; NaN stays NaN. (Its payload may not: torch
    converts a float32 NaN to the bfloat16 0xFFFF, and the bfloat16 stages compute in float32.)"""
    depth = torch.full((1, 1, 6, 7), 2.0, dtype=dtype)
    depth[0, 0, 1, 2], depth[0, 0, 3, 3], depth[0, 0, 4, 5] = math.nan, -0.0, -math.inf
    depth[0, 0, 5, 0] = -1.0
    amplitude = torch.full_like(depth, 100.0)
    invalid = ~valid_mask(depth)
    assert int(invalid.sum()) == 4
    outs = {
        "fpn_filter": fpn_filter(depth, _taps(20)),
        "suppression": _stage(-1, True)(depth, amplitude),
        "fusion": amplitude_fusion(depth + 1, depth, amplitude),
        "nlm": non_local_means(depth, sigma=0.1, patch_size=3, patch_distance=2),
    }
    for name, out in outs.items():
        _check_invalid_kept_valid_finite(out, depth, invalid)
        assert torch.isnan(out[0, 0, 1, 2]), name
        codes = torch.stack([out[0, 0, 3, 3], out[0, 0, 4, 5], out[0, 0, 5, 0]])
        assert (
            codes.view(BITS[dtype]).tolist()
            == torch.tensor([-0.0, -math.inf, -1.0], dtype=dtype).view(BITS[dtype]).tolist()
        ), name
