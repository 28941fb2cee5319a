"""FPNFilter with invalid pixels and isolated outliers: the fill rule and the outlier rule against a
NumPy implementation written from their description (runtime/holes.py), the bound on how far a
valid pixel moves (synthetic frames and the real ADTF3175 wall), bit-exact invalid pixels, and the
chunked inference path against the branch-free one."""

from __future__ import annotations

import importlib
import math

import numpy as np
import pytest
import scipy.ndimage as ndi
import torch

from tof_fpn_torch import FPNFilter, design_fpn
from tof_fpn_torch.build import filter_from_design, suppression_from_design
from tof_fpn_torch.runtime import valid_mask

fpn_filter_module = importlib.import_module("tof_fpn_torch.runtime.fpn_filter")
holes_module = importlib.import_module("tof_fpn_torch.runtime.holes")
SCIPY_MODE = {"reflect": "mirror", "replicate": "nearest", "circular": "wrap", "zeros": "constant"}
RATIO = 3.0  # an outlier is more than 3 times as far as each valid neighbour, or under a third


# --- the rule in NumPy, one line at a time -----------------------------------------------------


def ref_outliers(x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Valid pixels more than RATIO times as far as each valid neighbour at distance 1 on the line,
    or less than 1 / RATIO as far as each (none when there is no valid neighbour)."""
    out = np.zeros(x.shape, bool)
    for c in range(x.size):
        if not valid[c]:
            continue
        nbs = [x[k] for k in (c - 1, c + 1) if 0 <= k < x.size and valid[k]]
        if nbs and (all(x[c] > RATIO * n for n in nbs) or all(RATIO * x[c] < n for n in nbs)):
            out[c] = True
    return out


def ref_fill(x: np.ndarray, usable: np.ndarray, taps: int) -> np.ndarray:
    """Blocks of 8 from the line start; block sums and counts of the usable depths smoothed with
    the weights K + 1 - |j|, K = ceil((taps // 2) / 8); a pixel that is not usable gets its
    block's ratio. NaN where no usable depth is in reach (no valid output may read those)."""
    w, b = x.size, 8
    nb, k = -(-w // b), -(-(taps // 2) // b)
    s, n = np.zeros(nb), np.zeros(nb)
    for c in range(w):
        if usable[c]:
            s[c // b] += x[c]
            n[c // b] += 1
    f = x.astype(np.float64).copy()
    for c in range(w):
        if usable[c]:
            continue
        blk = c // b
        num = sum((k + 1 - abs(j)) * s[blk + j] for j in range(-k, k + 1) if 0 <= blk + j < nb)
        den = sum((k + 1 - abs(j)) * n[blk + j] for j in range(-k, k + 1) if 0 <= blk + j < nb)
        f[c] = num / den if den > 0 else np.nan
    return f


def ref_pass(x: np.ndarray, valid: np.ndarray, taps: np.ndarray, border: str) -> tuple:
    """One filtered axis (the last): (output, usable, filled lines)."""
    out, usable, filled = x.astype(np.float64).copy(), np.zeros(x.shape, bool), np.zeros(x.shape)
    for idx in np.ndindex(*x.shape[:-1]):
        line, v = x[idx].astype(np.float64), valid[idx]
        u = v & ~ref_outliers(line, v)
        f = ref_fill(line, u, taps.size)
        y = ndi.convolve1d(f, taps, mode=SCIPY_MODE[border])
        good = u & np.isfinite(y) & (y > 0)  # a valid pixel that would ring to <= 0 keeps x
        out[idx] = np.where(good, y, line)
        usable[idx], filled[idx] = u, f
        assert np.isfinite(y[u]).all()  # no usable output reads an unreachable fill
    return out, usable, filled


def reference(x: torch.Tensor, taps: np.ndarray, dims, border="reflect", mask=None) -> np.ndarray:
    xn = x.double().numpy()
    valid = valid_mask(x, mask=mask).numpy()
    for d in dims:
        if d == -2:
            xn, valid = np.swapaxes(xn, -1, -2), np.swapaxes(valid, -1, -2)
        xn = ref_pass(xn, valid, taps, border)[0]
        if d == -2:
            xn, valid = np.swapaxes(xn, -1, -2), np.swapaxes(valid, -1, -2)
    return xn


def _depth(shape, seed=0, holes=0.05):
    """Smooth positive depth (metres) with noise, 5 % zeros, a few NaN, spikes and dips."""
    g = torch.Generator().manual_seed(seed)
    b, c, h, w = shape
    yy = torch.linspace(0, 1, h).view(1, 1, -1, 1)
    xx = torch.linspace(0, 1, w).view(1, 1, 1, -1)
    x = 1.5 + 0.6 * yy + 0.4 * torch.sin(3.0 * xx + torch.rand(b, 1, 1, 1, generator=g))
    x = x + 0.01 * torch.randn(shape, generator=g) + 0.005 * torch.cos(torch.pi * torch.arange(w))
    flat = x.view(-1)
    idx = torch.randperm(flat.numel(), generator=g)
    k = int(holes * flat.numel())
    flat[idx[:k]] = 0.0
    flat[idx[k : k + 3]] = float("nan")
    flat[idx[k + 3 : k + 9]] *= 10.0  # isolated spikes (a 3.6 m return on a 0.35 m wall)
    flat[idx[k + 9 : k + 12]] *= 0.1  # and dips
    return x


# --- the rule -----------------------------------------------------------------------------------


@pytest.mark.parametrize("order", [20, 41])
@pytest.mark.parametrize("dims", [(-1,), (-2,), (-2, -1)])
@pytest.mark.parametrize("width", [64, 77])
def test_matches_numpy_reference(order, dims, width):
    """Zeros, NaN, spikes, dips, a caller's mask, a width that is not a multiple of 8."""
    f = filter_from_design(order, 0.14 if order == 20 else 0.12, dim=dims)
    x = _depth((2, 1, 40, width), seed=order + width)
    mask = torch.ones_like(x, dtype=torch.bool)
    mask[0, 0, 5, 10:14] = False
    for m in (None, mask):
        with torch.inference_mode():
            y = f(x, m)
        ref = reference(x, f.taps.numpy(), dims, mask=m)
        np.testing.assert_allclose(y.double().numpy(), ref, rtol=0, atol=2e-5, equal_nan=True)


@pytest.mark.parametrize("border", list(SCIPY_MODE))
def test_border_modes_and_float64(border):
    taps = design_fpn(20, 0.14).taps
    f = FPNFilter(taps, border=border)
    x = _depth((1, 2, 9, 50), seed=3).double()
    with torch.inference_mode():
        y = f(x)
    np.testing.assert_allclose(y.numpy(), reference(x, taps, (-1,), border), atol=1e-12)


def test_outliers_found_as_described():
    x = torch.tensor([[1.0, 1.1, 5.0, 1.2, 1.0, 0.0, 9.0, 1.0, 1.0, 0.3, 1.0, 2.9, 1.0, 3.1]])
    v = valid_mask(x).to(x.dtype)
    got = holes_module.isolated_outliers(x * v, v)[0].tolist()
    want = ref_outliers(x[0].numpy(), v[0].numpy() > 0).tolist()
    assert got == want
    # 5.0 (> 3x both), 9.0 (its only valid neighbour 1.0), 0.3 (< 1/3 of both), and 3.1 at the end
    # (only neighbour 1.0); not 2.9 (under 3x), not the pixels next to the spikes
    assert [i for i, o in enumerate(got) if o] == [2, 6, 9, 13]
    lonely = torch.tensor([[0.0, 5.0, 0.0, 1.0]])  # no valid neighbour: not tested
    lv = valid_mask(lonely).to(lonely.dtype)
    assert not holes_module.isolated_outliers(lonely, lv).any()


def test_invalid_pixels_come_out_bit_for_bit():
    f = filter_from_design(20, 0.14)
    x = _depth((1, 1, 30, 64), seed=5)
    codes = torch.tensor([0.0, -0.0, -1.0, math.inf, -math.inf, math.nan, -math.nan])
    x[0, 0, 3, 5 : 5 + codes.numel()] = codes
    for inp in (x, torch.where(torch.isnan(x), torch.zeros_like(x), x)):  # general, zeros only
        with torch.inference_mode():
            y = f(inp)
        invalid = ~valid_mask(inp)
        assert torch.equal(y[invalid].view(torch.int32), inp[invalid].view(torch.int32))
        assert bool(valid_mask(y)[~invalid].all())


def test_chunked_inference_equals_the_branch_free_path(monkeypatch):
    """Small chunks (several per call, outliers in some of them only) against the path taken
    when tracing for export."""
    f = filter_from_design(41, 0.12, dim=(-2, -1))
    x = _depth((2, 1, 70, 96), seed=7)
    monkeypatch.setattr(holes_module, "_chunk_samples", lambda: 1000)
    with torch.inference_mode():
        fast = f(x)
        monkeypatch.setattr(fpn_filter_module, "_tracing", lambda: True)
        exact = f(x)
    torch.testing.assert_close(fast, exact, rtol=0, atol=2e-6, equal_nan=True)


# --- the bound ----------------------------------------------------------------------------------


def _bound_violations(x, y, taps, dims=(-1,), valid=None):
    """Pixels where ``|y - x| > sum|h - delta| * max |x_m - x_n| + |H(0) - 1| |x_n|`` over the
    usable pixels m within ``L // 2 + 8 K + 7`` of n along the axis (runtime/holes.py), for one
    filtered axis; returns (count, worst excess, largest move)."""
    (d,) = dims
    xn, yn = x.double().numpy(), y.double().numpy()
    v = (valid_mask(x) if valid is None else valid).numpy()
    if d == -2:
        xn, yn, v = (np.swapaxes(a, -1, -2) for a in (xn, yn, v))
    h = np.asarray(taps, np.float64)
    delta = np.zeros_like(h)
    delta[h.size // 2] = 1.0
    gain, dc = np.abs(h - delta).sum(), abs(h.sum() - 1.0)
    reach = h.size // 2 + 8 * (-(-(h.size // 2) // 8)) + 7
    count, excess, moved = 0, 0.0, 0.0
    for idx in np.ndindex(*xn.shape[:-1]):
        line, out, vv = xn[idx], yn[idx], v[idx]
        u = vv & ~ref_outliers(line, vv)
        for n in np.flatnonzero(u):
            lo, hi = max(0, n - reach), min(line.size, n + reach + 1)
            near = line[lo:hi][u[lo:hi]]
            allowed = gain * np.abs(near - line[n]).max() + dc * abs(line[n]) + 1e-5 * line[n]
            move = abs(out[n] - line[n])
            moved = max(moved, move)
            if move > allowed:
                count, excess = count + 1, max(excess, move - allowed)
    return count, excess, moved


def test_bound_holds_next_to_holes_and_outliers():
    """A frame whose pixels next to spikes moved by tens of centimetres before."""
    f = filter_from_design(20, 0.14)
    x = _depth((2, 1, 24, 96), seed=11, holes=0.08)
    with torch.inference_mode():
        y = f(x)
    count, excess, _ = _bound_violations(x, y, f.taps.numpy())
    assert count == 0, (count, excess)
    # and the spikes themselves came back unchanged
    lines, valid = x.view(-1, 96).numpy(), valid_mask(x).view(-1, 96).numpy()
    spikes = torch.from_numpy(
        np.stack([ref_outliers(r, m) for r, m in zip(lines, valid, strict=True)])
    )
    assert int(spikes.sum()) >= 6 and torch.equal(y.view(-1, 96)[spikes], x.view(-1, 96)[spikes])


@pytest.mark.parametrize("gate", [False, True])
def test_bound_holds_on_the_real_wall(real_data, gate):
    """The ADTF3175 wall (metres): a 3.6 m return next to an invalid pixel among 0.35 m used to
    move 11 valid neighbours by up to 786 mm with the stage ungated. The stage's fusion and gate
    weigh the filter's change by factors in [0, 1], so the filter's bound holds for the stage."""
    depth, ir = real_data.adi_wall()
    d = depth / 1000.0
    stage = suppression_from_design(gate=gate)
    with torch.inference_mode():
        out = stage(d, ir)
    count, excess, moved = _bound_violations(d, out, stage.filter.taps.numpy())
    assert count == 0, (count, excess)
    assert moved < 0.05  # metres: the wall's noise, not the 3.3 m step to the spike
    valid = valid_mask(d, ir)
    assert torch.equal(out[~valid], d[~valid]) and bool(valid_mask(out)[valid].all())


def test_state_dicts_of_earlier_versions_load():
    """Earlier versions kept a hole-fill window as a buffer: their state dicts still load."""
    f = filter_from_design(20, 0.14)
    state = dict(f.state_dict())
    state["window"] = torch.ones(23, dtype=torch.float64)
    g = filter_from_design(20, 0.14)
    g.load_state_dict(state)
    assert torch.equal(g.taps, f.taps) and "window" not in g.state_dict()
