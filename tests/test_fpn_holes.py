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


def ref_image_outliers(x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The outliers of one (H, W) image filtered along its rows: line outliers (above) that have
    an invalid pixel in their 3 x 3 neighbourhood and no other line outlier there."""
    line = np.stack([ref_outliers(x[r], valid[r]) for r in range(x.shape[0])])
    out = np.zeros_like(line)
    h, w = line.shape
    for r, c in zip(*np.nonzero(line), strict=True):
        nb = [(i, j) for i in range(r - 1, r + 2) for j in range(c - 1, c + 2)]
        nb = [(i, j) for i, j in nb if 0 <= i < h and 0 <= j < w and (i, j) != (r, c)]
        out[r, c] = any(not valid[i, j] for i, j in nb) and not any(line[i, j] for i, j in nb)
    return out


def ref_pass(x: np.ndarray, valid: np.ndarray, taps: np.ndarray, border: str) -> np.ndarray:
    """One filtered axis (the last): at a usable pixel n the filter of the line in which every
    pixel that is not usable holds x_n (the weight of those taps goes to n itself); the input
    elsewhere, and where the output would not be a valid depth."""
    out = x.astype(np.float64).copy()
    c, pad = taps.size // 2, taps.size  # c: the tap that multiplies the pixel itself

    def padded(a, outside):  # the border modes; ``zeros``: outside is a usable 0
        if border == "zeros":
            return np.pad(a, pad, mode="constant", constant_values=outside)
        return np.pad(a, pad, mode={"reflect": "reflect", "replicate": "edge"}.get(border, "wrap"))

    odd = np.zeros(x.shape, bool)
    for img in np.ndindex(*x.shape[:-2]):
        odd[img] = ref_image_outliers(x[img], valid[img])
    for idx in np.ndindex(*x.shape[:-1]):
        line, v = x[idx].astype(np.float64), valid[idx]
        usable = v & ~odd[idx]
        ext, use = padded(np.where(usable, line, 0.0), 0.0), padded(usable, True)
        y = np.empty(line.size)
        for n in range(line.size):  # y_n = sum_k h_k (x_{n+c-k} if usable else x_n)
            src = n + pad + c - np.arange(taps.size)
            y[n] = np.sum(taps * np.where(use[src], ext[src], line[n]))
        good = usable & np.isfinite(y) & (y > 0)
        out[idx] = np.where(good, y, line)
    return out


def reference(x: torch.Tensor, taps: np.ndarray, dims, border="reflect", mask=None) -> np.ndarray:
    xn = x.double().numpy()
    valid = valid_mask(x, mask=mask).numpy()
    for d in dims:
        if d == -2:
            xn, valid = np.swapaxes(xn, -1, -2), np.swapaxes(valid, -1, -2)
        xn = ref_pass(xn, valid, taps, border)
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
    """Also against SciPy in the form the module computes: ``h * x0 + (h * u) x`` with ``x0`` the
    zero-filled depth and ``u`` the indicator of the pixels that are not usable (padded like the
    depth; ``zeros``: outside is a usable 0)."""
    taps = design_fpn(20, 0.14).taps
    f = FPNFilter(taps, border=border)
    x = _depth((1, 2, 9, 50), seed=3).double()
    with torch.inference_mode():
        y = f(x).numpy()
    np.testing.assert_allclose(y, reference(x, taps, (-1,), border), atol=1e-12)
    xn, valid = x.numpy(), valid_mask(x).numpy()
    usable = np.stack(
        [valid[0, c] & ~ref_image_outliers(xn[0, c], valid[0, c]) for c in range(2)]
    ).reshape(x.shape)
    x0 = np.where(usable, xn, 0.0)
    mode = SCIPY_MODE[border]
    form = (
        ndi.convolve1d(x0, taps, mode=mode) + ndi.convolve1d((~usable) * 1.0, taps, mode=mode) * x0
    )
    ok = usable & (form > 0)  # where the form rings to <= 0 (a spike in the open) the input stays
    np.testing.assert_allclose(y[ok], form[ok], atol=1e-12)
    np.testing.assert_array_equal(y[usable & ~ok], xn[usable & ~ok])


def test_outliers_found_as_described():
    x = torch.tensor([[1.0, 1.1, 5.0, 1.2, 1.0, 0.0, 9.0, 1.0, 1.0, 0.3, 1.0, 2.9, 1.0, 3.1]])
    v = valid_mask(x).to(x.dtype)
    line = ref_outliers(x[0].numpy(), v[0].numpy() > 0)
    # far from each valid neighbour: 5.0 (> 3x both), 9.0 (its only valid neighbour 1.0), 0.3 (<
    # 1/3 of both), 3.1 at the end (only neighbour 1.0); not 2.9 (under 3x), not their neighbours
    assert [i for i, o in enumerate(line) if o] == [2, 6, 9, 13]
    # an outlier is one of those next to a hole: on a lone line, 9.0 only
    got = holes_module.isolated_outliers(x * v, v)[0].tolist()
    assert [i for i, o in enumerate(got) if o] == [6]
    lonely = torch.tensor([[0.0, 5.0, 0.0, 1.0]])  # no valid neighbour: not tested
    lv = valid_mask(lonely).to(lonely.dtype)
    assert not holes_module.isolated_outliers(lonely, lv).any()
    # in an image: a spike beside a hole is one; a spike in the open is not; a bar one pixel wide
    # beside holes is not either (a run of them: scene), against the NumPy reference
    img = torch.full((6, 9), 1.0)
    img[1, 3], img[1, 4] = 0.0, 8.0  # a spike beside a hole
    img[4, 1] = 8.0  # a spike in the open
    img[:, 7], img[2, 6] = 0.2, 0.0  # a thin near bar, a hole beside it
    iv = valid_mask(img).to(img.dtype)
    got = holes_module.isolated_outliers(img * iv, iv, lines=6)
    want = ref_image_outliers(img.numpy(), iv.numpy() > 0)
    assert got.tolist() == want.tolist()
    assert [tuple(p) for p in torch.nonzero(got).tolist()] == [(1, 4)]


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
    """Pixels where ``|y - x| > sum_{k != c} |h_k| * max |x_m - x_n| + |H(0) - 1| |x_n|`` over the
    usable pixels m the filter reaches from n along the axis (runtime/holes.py), for one filtered
    axis; returns (count, worst excess, largest move)."""
    (d,) = dims
    xn, yn = x.double().numpy(), y.double().numpy()
    v = (valid_mask(x) if valid is None else valid).numpy()
    if d == -2:
        xn, yn, v = (np.swapaxes(a, -1, -2) for a in (xn, yn, v))
    h = np.asarray(taps, np.float64)
    gain, dc = np.abs(h).sum() - abs(h[h.size // 2]), abs(h.sum() - 1.0)
    right = h.size // 2
    left = h.size - 1 - right
    count, excess, moved = 0, 0.0, 0.0
    usable = np.zeros(v.shape, bool)
    for img in np.ndindex(*xn.shape[:-2]):
        usable[img] = v[img] & ~ref_image_outliers(xn[img], v[img])
    for idx in np.ndindex(*xn.shape[:-1]):
        line, out, u = xn[idx], yn[idx], usable[idx]
        for n in np.flatnonzero(u):
            lo, hi = max(0, n - left), min(line.size, n + right + 1)
            near = line[lo:hi][u[lo:hi]]
            allowed = gain * np.abs(near - line[n]).max() + dc * abs(line[n]) + 1e-5 * line[n]
            move = abs(out[n] - line[n])
            moved = max(moved, move)
            if move > allowed:
                count, excess = count + 1, max(excess, move - allowed)
    return count, excess, moved


def test_bound_holds_next_to_holes_and_outliers():
    """A frame whose pixels next to spikes moved by tens of centimetres before (a spike next to a
    hole is an outlier; one in the open is scene, and the bound allows what it moves)."""
    f = filter_from_design(20, 0.14)
    x = _depth((2, 1, 24, 96), seed=11, holes=0.08)
    with torch.inference_mode():
        y = f(x)
    count, excess, _ = _bound_violations(x, y, f.taps.numpy())
    assert count == 0, (count, excess)
    # and the spikes next to holes themselves came back unchanged
    xn, valid = x.numpy(), valid_mask(x).numpy()
    spikes = torch.from_numpy(
        np.stack([ref_image_outliers(xn[b, 0], valid[b, 0]) for b in range(2)])
    ).view(x.shape)
    assert int(spikes.sum()) >= 2 and torch.equal(y[spikes], x[spikes])


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


@pytest.mark.parametrize("border", list(SCIPY_MODE))
def test_a_valid_pixel_never_comes_out_invalid(border):
    """A steep step (0.3 m to 3 m) makes the filter ring below 0 next to it, and the ``zeros``
    border pulls the first and last columns towards 0: the input is kept there, with and
    without holes."""
    f = filter_from_design(20, 0.14, border=border)
    x = torch.full((2, 1, 6, 64), 3.0)
    x[..., 32:] = 0.3
    x[1, 0, 2, 10] = 0.0  # a hole in the second image
    with torch.inference_mode():
        y = f(x)
    valid = valid_mask(x)
    assert bool(valid_mask(y)[valid].all()) and torch.equal(y[~valid], x[~valid])
    ref = reference(x, f.taps.numpy(), (-1,), border)
    np.testing.assert_allclose(y.double().numpy(), ref, rtol=0, atol=2e-5)


# --- the chunked inference path against the previous implementation ----------------------------


def _previous_holed_lines(x2, valid2, taps, border, ops, gains, top, lines=0, zeros=True):
    """The chunked inference path as it was before the padded-buffer kernel, kept as a reference:
    per chunk the zero-filled depth and the indicator as one (2 R, W) block through the FIR with
    its row borders redone, the validity from a mask computed for the whole frame (NaN frames)."""
    from tof_fpn_torch.runtime.fir import fir_last

    if valid2 is None and not zeros:
        valid2 = valid_mask(x2)
    r, w = x2.shape
    out = torch.empty_like(x2)
    rows = max(1, 4096 // w)
    odd_all = None
    for r0 in range(0, r, rows):
        r1 = min(r, r0 + rows)
        xc = x2[r0:r1]
        both = torch.empty((2, r1 - r0, w), dtype=x2.dtype)
        x0, u = both[0], both[1]
        if valid2 is not None:
            torch.where(valid2[r0:r1], xc, torch.zeros_like(xc), out=x0)
            u.copy_(~valid2[r0:r1])
            peak = float(x0.amax())
        else:
            x0.copy_(xc)
            torch.le(xc, 0.0, out=u)
            peak = top
        lo, hi = torch.aminmax(torch.addcmul(x0, u, torch.full_like(x0[:1, :1], peak)))
        if not bool(hi < RATIO * lo):
            if odd_all is None:
                vall = (x2 > 0) if valid2 is None else valid2
                x0all = torch.where(vall, x2, torch.zeros_like(x2))
                odd_all = holes_module.isolated_outliers(x0all, vall.to(x2.dtype), lines)
            odd = odd_all[r0:r1]
            u.masked_fill_(odd, 1.0)
            x0.masked_fill_(odd, 0.0)
            lo, hi = torch.aminmax(torch.addcmul(x0, u, torch.full_like(x0[:1, :1], peak)))
        y2 = fir_last(both.view(-1, w), taps, border, ops, True)
        y = y2[: r1 - r0].addcmul_(y2[r1 - r0 :], x0)
        oc = out[r0:r1]
        torch.where(u > 0, xc, y, out=oc)
        if not holes_module.certified(float(lo), float(hi), gains, border):
            oc.copy_(torch.where((u < 1) & ~valid_mask(oc), xc, oc))
    return out


def _holed_frames(shape, seed):
    """Depth 1.5-3.5 m with 1 % and 10 % holes as 0 and as NaN, holes in the first and last
    columns, a row with no valid pixel (0 in one image, NaN in the other), a spike next to a hole
    (an outlier); one frame with other codes among the NaN (-0.0, -1, +-inf, 0) and one whose
    depths span more than a factor 3 (the outlier search)."""
    g = torch.Generator().manual_seed(seed)
    b, c, h, w = shape
    yy = torch.linspace(0, 1, h).view(1, 1, -1, 1)
    xx = torch.linspace(0, 1, w).view(1, 1, 1, -1)
    base = 1.5 + 1.0 * yy + 0.5 * torch.sin(4.0 * xx + torch.rand(b, 1, 1, 1, generator=g))
    base = base + 0.01 * torch.randn(shape, generator=g)
    frames = []
    for p in (0.01, 0.1):
        x = base.clone()
        holes = torch.rand(shape, generator=g) < p
        holes[..., 3, 0] = holes[..., 4, -1] = True
        x[holes] = 0.0
        x[0, 0, 5] = 0.0  # a row without a valid pixel
        x[-1, 0, 6, w // 2 - 1], x[-1, 0, 6, w // 2] = 0.0, 20.0  # a spike next to a hole
        frames.append(x)
        nan = torch.where(x == 0, torch.full_like(x, math.nan), x)
        nan[-1, 0, 5] = math.nan
        frames.append(nan)
    mixed = frames[-1].clone()  # other codes among the NaN: -0.0, -1, +-inf, 0
    codes = torch.tensor([-0.0, -1.0, math.inf, -math.inf, 0.0])
    idx = torch.nonzero(torch.isnan(mixed.view(-1))).view(-1)[::3][:50]
    mixed.view(-1)[idx] = codes.repeat(10)[: idx.numel()]
    frames.append(mixed)
    wide = base.clone()
    wide[..., : w // 3] *= 0.2  # 0.3-0.7 m beside 1.5-3.5 m
    wide[torch.rand(shape, generator=g) < 0.05] = math.nan
    frames.append(wide)
    return frames


@pytest.mark.parametrize("order", [20, 41])
@pytest.mark.parametrize("border", list(SCIPY_MODE))
@pytest.mark.parametrize("width", [5, 30, 77, 512])
def test_chunks_equal_the_previous_implementation(monkeypatch, order, border, width):
    """NaN and 0 holes, several chunks per call (the last one shorter), lines narrower than the
    filter (the padding gathered) and wider: the same output as before to float32 rounding, the
    invalid pixels bit for bit, along either axis."""
    f = filter_from_design(order, 0.14 if order == 20 else 0.12, border=border, dim=(-2, -1))
    monkeypatch.setattr(holes_module, "_chunk_samples", lambda: 3000)
    frames = _holed_frames((2, 1, 48, width), seed=order + width)
    for x in frames:
        with torch.inference_mode():
            new = f(x)
            monkeypatch.setattr(fpn_filter_module, "holed_lines", _previous_holed_lines)
            old = f(x)
            monkeypatch.undo()
            monkeypatch.setattr(holes_module, "_chunk_samples", lambda: 3000)
        scale = float(torch.nan_to_num(x, 0.0).abs().max())
        torch.testing.assert_close(new, old, rtol=0, atol=8e-7 * scale, equal_nan=True)
        invalid = ~valid_mask(x)
        assert torch.equal(new[invalid].view(torch.int32), x[invalid].view(torch.int32))
        assert bool(valid_mask(new)[~invalid].all())


@pytest.mark.parametrize("border", list(SCIPY_MODE))
def test_nan_and_zero_holes_match_numpy_reference(border):
    """The per-pixel NumPy loop on frames with holes as 0 and as NaN (edges, an all-invalid
    row, a spike next to a hole), filtered along the rows: NaN and 0 give the same valid pixels."""
    f = filter_from_design(20, 0.14, border=border)
    zero = _holed_frames((2, 1, 12, 64), seed=4)[2]
    nan = torch.where(zero == 0, torch.full_like(zero, math.nan), zero)
    with torch.inference_mode():
        yz, yn = f(zero), f(nan)
    for x, y in ((zero, yz), (nan, yn)):
        ref = reference(x, f.taps.numpy(), (-1,), border)
        np.testing.assert_allclose(y.double().numpy(), ref, rtol=0, atol=2e-5, equal_nan=True)
    valid = valid_mask(zero)
    assert torch.equal(yz[valid], yn[valid]) and bool(torch.isnan(yn[~valid]).all())
    assert torch.equal(yz[~valid], zero[~valid])


def test_torchscript_equals_eager_with_holes():
    """NaN, 0 and mixed codes through a scripted module (its write-back without bit views)."""
    f = filter_from_design(41, 0.12, dim=(-2, -1))
    scripted = torch.jit.script(f)
    codes = _depth((2, 1, 40, 77), seed=9)
    for x in [*_holed_frames((2, 1, 40, 77), seed=8), codes]:
        with torch.inference_mode():
            eager, script = f(x), scripted(x)
        torch.testing.assert_close(script, eager, rtol=0, atol=2e-6, equal_nan=True)
        invalid = ~valid_mask(x)
        assert torch.equal(script[invalid].view(torch.int32), x[invalid].view(torch.int32))


def test_nan_payloads_come_back_and_a_signalling_nan_stays_nan():
    """Quiet NaNs keep sign and payload (the other codes: the frames above); a signalling NaN
    comes back as a (quiet) NaN."""
    f = filter_from_design(20, 0.14)
    x = _holed_frames((1, 1, 30, 64), seed=2)[1]  # NaN holes
    payloads = torch.tensor([0x7FC12345, -0x3FEDCBA], dtype=torch.int32).view(torch.float32)
    x[0, 0, 7, 3:5] = payloads
    with torch.inference_mode():
        y = f(x)
    invalid = ~valid_mask(x)
    assert torch.equal(y[invalid].view(torch.int32), x[invalid].view(torch.int32))
    x[0, 0, 11, 30] = torch.tensor([0x7F812345], dtype=torch.int32).view(torch.float32)
    with torch.inference_mode():
        assert bool(torch.isnan(f(x)[0, 0, 11, 30]))


@pytest.mark.parametrize("length", [1, 2, 3, 6])
@pytest.mark.parametrize("border", list(SCIPY_MODE))
def test_tiny_frames_and_short_taps_equal_the_branch_free_path(monkeypatch, length, border):
    """Frames of 1 x 1 to 9 x 7 pixels (smaller than the kernel's smallest input: the other FIR
    kernel) and 1 to 6 taps (odd and even), NaN and 0 holes and other codes, both axes."""
    taps = torch.linspace(1.0, 2.0, length) / torch.linspace(1.0, 2.0, length).sum()
    f = FPNFilter(taps, border=border, allow_shift=True, dim=(-2, -1))
    for h, w in ((1, 1), (1, 7), (9, 2), (9, 7)):
        for x in _holed_frames((2, 1, 9, w), seed=w)[:6]:
            x = x[:, :, :h].contiguous()
            with torch.inference_mode():
                fast = f(x)
                monkeypatch.setattr(fpn_filter_module, "_tracing", lambda: True)
                exact = f(x)
                monkeypatch.undo()
            torch.testing.assert_close(fast, exact, rtol=0, atol=2e-6, equal_nan=True)
            invalid = ~valid_mask(x)
            assert torch.equal(fast[invalid].view(torch.int32), x[invalid].view(torch.int32))
