"""The flying-pixel stage (tof_fpn_torch.runtime.flying): planted mixed pixels are flagged, slopes,
flat areas and thin bars are kept, invalid pixels pass bit for bit, TorchScript and ONNX equal eager,
bad input is refused, the output follows the input's device and dtype."""

from __future__ import annotations

import math

import pytest
import torch

from tof_fpn_torch.runtime import FlyingPixels, flying_pixels
from tof_fpn_torch.runtime.flying import ACTIONS
from tof_fpn_torch.runtime.stage import RecordOutputs

NOISE = 0.003


def planted(seed: int = 0, h: int = 48, w: int = 80):
    """A slanted wall at 2-2.4 m, a box at 1 m (columns 48-65), one column of mixed pixels at its
    left edge (column 47: 1.5 m, the amplitude of a mixture), bars 1, 2 and 3 px wide at 1.2 m
    on the wall (columns 9, 19-20, 31-33: the wall around them is wider than the facets, see
    docs/flying.md), 3 mm noise; returns depth, amplitude, the mixed mask and the bar mask."""
    g = torch.Generator().manual_seed(seed)
    yy = torch.arange(h, dtype=torch.float32).view(-1, 1)
    xx = torch.arange(w, dtype=torch.float32).view(1, -1)
    depth = (2.0 + 0.005 * yy + 0.002 * xx).expand(h, w).clone()
    amp = torch.full((h, w), 100.0)
    depth[:, 48:66] = 1.0
    amp[:, 48:66] = 400.0
    mixed = torch.zeros(h, w, dtype=torch.bool)
    mixed[8:40, 47] = True
    depth[mixed] = 1.5
    amp[mixed] = 250.0
    bars = torch.zeros(h, w, dtype=torch.bool)
    for c0, c1 in ((9, 10), (19, 21), (31, 34)):
        bars[10:38, c0:c1] = True
    depth[bars] = 1.2
    amp[bars] = 300.0
    depth = depth + NOISE * torch.randn(h, w, generator=g)
    amp = amp * (1 + 0.02 * torch.randn(h, w, generator=g))
    return depth.view(1, 1, h, w), amp.view(1, 1, h, w), mixed, bars


def test_planted_mixed_column_flagged_and_nothing_else():
    depth, amp, mixed, bars = planted()
    for a in (amp, None):
        _, conf = flying_pixels(depth, a)
        flagged = (conf < 0.5)[0, 0]
        assert bool(flagged[mixed].all()), "every planted mixed pixel is flagged"
        rows = slice(12, 36)  # away from the column's and bars' ends (those are edges too)
        assert int(flagged[rows][~mixed[rows]].sum()) == 0, "nothing else is flagged"


def test_thin_bars_and_flat_slope_are_kept():
    depth, amp, _, bars = planted(1)
    for action in ("invalidate", "reassign"):
        out, conf = flying_pixels(depth, amp, action=action)
        inner = bars.clone()
        inner[:12] = False
        inner[36:] = False
        assert bool((conf[0, 0][inner] >= 0.5).all())
        assert torch.equal(out[0, 0][inner], depth[0, 0][inner])
    wall = torch.zeros_like(bars)
    wall[4:44, 38:42] = True  # slanted wall between the bars and the box's mixed column
    wall[4:44, 70:76] = True
    assert bool((conf[0, 0][wall] >= 0.5).all())


def test_step_without_mixing_is_not_flagged():
    depth, amp, mixed, _ = planted(2)
    depth[0, 0][mixed] = 1.0  # the column now belongs to the box: a clean step
    amp[0, 0][mixed] = 400.0
    _, conf = flying_pixels(depth, amp)
    # noise alone flags a few scattered pixels (0.05 % here): none on the step
    assert int((conf < 0.5).sum()) <= 0.002 * depth.numel()
    assert int((conf < 0.5)[0, 0][:, 44:52].sum()) == 0


def test_actions():
    depth, amp, mixed, _ = planted(3)
    marked, conf = flying_pixels(depth, amp, action="mark")
    assert torch.equal(marked, depth) and marked is not depth
    inv, _ = flying_pixels(depth, amp, action="invalidate")
    flagged = (conf < 0.5)[0, 0]
    assert bool((inv[0, 0][flagged] == 0).all())
    assert torch.equal(inv[0, 0][~flagged], depth[0, 0][~flagged])
    nan, _ = flying_pixels(depth, amp, action="invalidate", fill=math.nan)
    assert bool(nan[0, 0][flagged].isnan().all())
    re, _ = flying_pixels(depth, amp, action="reassign")
    # a mixed pixel at 1.5 m between the wall (~2.1 m) and the box (1.0 m) goes to the box,
    # whose depth is nearer: it takes a kept neighbour's value
    assert bool(((re[0, 0][mixed] - 1.0).abs() < 4 * NOISE).all())
    kept = depth[0, 0][~flagged]
    assert torch.equal(re[0, 0][~flagged], kept)


def test_invalid_pixels_pass_bit_for_bit():
    depth, amp, _, _ = planted(4)
    g = torch.Generator().manual_seed(4)
    holes = torch.rand(depth.shape, generator=g) < 0.05
    codes = torch.tensor([0.0, math.nan, -1.0, math.inf])
    pick = torch.randint(0, 4, depth.shape, generator=g)
    holed = torch.where(holes, codes[pick], depth)
    for action in ACTIONS:
        out, conf = flying_pixels(holed, amp, action=action)
        assert torch.equal(out[holes].view(torch.int32), holed[holes].view(torch.int32))
        assert bool((conf[holes] == 0).all())
    # a pixel all of whose facets touch a hole is never flagged
    solid = torch.zeros_like(holes)
    solid[..., 20:30, 36:44] = True  # 5 x 5 windows 3-4 px away all touch the ring
    ring = torch.zeros_like(holes)
    ring[..., 14:36, 30:50] = True
    ring[..., 16:34, 32:48] = False
    out, conf = flying_pixels(torch.where(ring, 0.0, depth), amp)
    assert bool((conf[solid] >= 0.5).all())


def test_confidence_range_and_threshold():
    depth, amp, _, _ = planted(5)
    _, conf = flying_pixels(depth, amp)
    assert conf.min() >= 0 and conf.max() <= 1 and conf.dtype == depth.dtype
    _, strict = flying_pixels(depth, amp, threshold=50.0)
    assert int((strict < 0.5).sum()) < int((conf < 0.5).sum())


def test_input_not_modified_and_dtype_device_follow():
    depth, amp, _, _ = planted(6)
    before = depth.clone()
    out, conf = flying_pixels(depth.double(), amp.double(), action="invalidate")
    assert torch.equal(depth, before)
    assert out.dtype == torch.float64 and conf.dtype == torch.float64
    assert out.device == depth.device and conf.device == depth.device
    out16, _ = flying_pixels(depth.half(), amp.half())
    assert out16.dtype == torch.float16


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_cuda_equals_cpu():
    depth, amp, _, _ = planted(7)
    out, rec = FlyingPixels("reassign").run(depth.cuda(), amp.cuda())
    ref, ref_rec = FlyingPixels("reassign").run(depth, amp)
    conf, ref_conf = rec["confidence"], ref_rec["confidence"]
    assert out.is_cuda and torch.allclose(out.cpu(), ref, atol=1e-5)
    assert torch.allclose(conf.cpu(), ref_conf, atol=1e-5)


def test_bad_input_is_refused_with_a_reason():
    depth, amp, _, _ = planted()
    with pytest.raises(TypeError, match="torch.Tensor"):
        flying_pixels(depth.numpy(), amp)
    with pytest.raises(ValueError, match=r"\(B, C, H, W\)"):
        flying_pixels(depth[0], amp[0])
    with pytest.raises(ValueError, match="1 channel"):
        flying_pixels(depth.repeat(1, 2, 1, 1))
    with pytest.raises(ValueError, match="same shape"):
        flying_pixels(depth, amp[..., 1:])
    with pytest.raises(ValueError, match="floating"):
        flying_pixels(depth.long(), amp)
    with pytest.raises(ValueError, match="action"):
        FlyingPixels("erase")
    with pytest.raises(ValueError, match="threshold"):
        flying_pixels(depth, amp, threshold=-1.0)


@pytest.mark.parametrize("action", ACTIONS)
def test_torchscript_equals_eager(action):
    depth, amp, _, _ = planted(8)
    depth[0, 0, 3, 3] = 0.0
    stage = FlyingPixels(action)
    scripted = torch.jit.script(stage)
    for a in (amp, None):
        torch.testing.assert_close(scripted(depth, a), stage(depth, a), atol=1e-5, rtol=0)
        (got, got_rec), (want, want_rec) = scripted.run(depth, a), stage.run(depth, a)
        torch.testing.assert_close(got, want, atol=1e-5, rtol=0, equal_nan=True)
        assert sorted(got_rec) == sorted(want_rec) == ["confidence", "flagged", "valid"]
        for key in want_rec:
            torch.testing.assert_close(got_rec[key], want_rec[key], atol=1e-5, rtol=0)


@pytest.mark.slow
def test_onnx_equals_eager(tmp_path):
    """Through the package's ``export_onnx`` (the class asks for the TorchScript-based exporter:
    seconds; ``torch.export`` took minutes on the unrolled loops), dynamic sizes."""
    import onnxruntime as ort

    from tof_fpn_torch.export import export_onnx

    depth, amp, _, _ = planted(9)
    stage = RecordOutputs(FlyingPixels("reassign"), ("confidence",))
    path = export_onnx(stage, tmp_path / "flying.onnx", example_inputs=(depth, amp))
    session = ort.InferenceSession(str(path))
    assert [o.name for o in session.get_outputs()] == ["output", "confidence"]
    other = planted(10, h=40, w=56)  # another size: the graph's shapes are dynamic
    for d, a in ((depth, amp), (torch.cat([other[0], other[0]]), torch.cat([other[1]] * 2))):
        got = session.run(None, {"depth": d.numpy(), "amplitude": a.numpy()})
        for g, want in zip(got, stage(d, a), strict=True):
            torch.testing.assert_close(torch.from_numpy(g), want, atol=1e-5, rtol=0)


def test_clean_flying_invalidates_and_records(tmp_path, capsys):
    import json

    import numpy as np
    from PIL import Image

    from tof_fpn_torch.cli import main

    folder = tmp_path / "in"
    folder.mkdir()
    depth, amp, mixed, _ = planted(11)
    Image.fromarray(np.round(depth[0, 0].numpy() * 1000).astype(np.uint16)).save(
        folder / "a_depth.png"
    )
    Image.fromarray(np.round(amp[0, 0].numpy()).astype(np.uint16)).save(folder / "a_amplitude.png")
    out = tmp_path / "out"
    args = ["clean", str(folder), str(out), "--notch", "off", "--destripe", "off", "--no-figure"]
    assert main([*args, "--flying", "invalidate", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "flying pixels: invalidate" in printed and "flying pixels: " in printed
    written = np.asarray(Image.open(out / "a_depth.png"))
    assert bool((written[mixed.numpy()] == 0).all())
    records = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    (rec,) = [r for r in records if r.get("status") == "done"]
    fly = rec["report"]["flying"]
    assert fly["flagged"] >= int(mixed.sum()) and fly["valid"] == depth.numel()
    assert "invalidate" in (out / "clean.toml").read_text()


def test_clean_writes_the_confidence_map(tmp_path):
    import json

    import numpy as np
    from PIL import Image

    from tof_fpn_torch.clean import CleanConfig
    from tof_fpn_torch.cli import main

    folder = tmp_path / "in"
    folder.mkdir()
    depth, amp, mixed, _ = planted(12)
    mm = np.round(depth[0, 0].numpy() * 1000).astype(np.uint16)
    Image.fromarray(mm).save(folder / "a_depth.png")
    Image.fromarray(np.round(amp[0, 0].numpy()).astype(np.uint16)).save(folder / "a_amplitude.png")
    out = tmp_path / "out"
    args = ["clean", str(folder), str(out), "--notch", "off", "--destripe", "off", "--no-figure"]
    assert main([*args, "--flying", "mark", "--flying-confidence", "--quiet"]) == 0
    conf = np.load(out / "a_depth.flying_confidence.npy")
    assert conf.dtype == np.float32 and conf.shape == (1, *mm.shape)
    stored = torch.from_numpy(mm.astype(np.float64) / 1000).float().view(1, 1, *mm.shape)
    want = flying_pixels(stored, amp.round())[1]  # the stage on what the file holds
    torch.testing.assert_close(torch.from_numpy(conf), want[0], atol=1e-5, rtol=0)
    assert bool((conf[0][mixed.numpy()] < 0.5).all())
    records = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    (rec,) = [r for r in records if r.get("status") == "done"]
    assert rec["flying_confidence"] == ["a_depth.flying_confidence.npy"]
    assert "flying_confidence = true" in (out / "clean.toml").read_text()
    with pytest.raises(ValueError, match="flying_confidence needs"):
        CleanConfig(flying_confidence=True)


def _holed_surface(seed: int, h: int = 14, w: int = 17) -> torch.Tensor:
    """A slanted float64 surface with a 1 m step, 5 mm noise and a few invalid pixels (NaN)."""
    g = torch.Generator().manual_seed(seed)
    yy = torch.arange(h, dtype=torch.float64).view(-1, 1)
    xx = torch.arange(w, dtype=torch.float64).view(1, -1)
    x = 2.0 + 0.01 * yy - 0.02 * xx + torch.where(xx > w // 2, 1.0, 0.0)
    x = x + 0.005 * torch.randn(h, w, generator=g, dtype=torch.float64)
    x[3, 4] = x[7, 10] = x[8, 10] = x[h - 1, 2] = math.nan
    return x.view(1, 1, h, w)


@pytest.mark.parametrize("size", [3, 5, 7])
def test_window_fit_equals_the_convolution_fit(size):
    """The shifted-add window sums give the plane fits of the convolution and residual loop
    (``plane_fit``), NaN where a window touches an invalid pixel or leaves the frame, also on the
    padded domain the facets need."""
    from torch.nn import functional as F

    from tof_fpn_torch.runtime._facets import plane_fit, window_fit, window_variance

    x = _holed_surface(size)
    want = plane_fit(x, size, size)
    for out in (0, 3):
        pad = out + size // 2 + 1
        got = window_fit(F.pad(x, (pad, pad, pad, pad), value=math.nan), pad, size, out)
        v = window_variance(F.pad(x, (pad, pad, pad, pad), value=math.nan), pad, size, out)
        torch.testing.assert_close(v, got[3], rtol=0, atol=0, equal_nan=True)
        ring = torch.ones_like(got[0], dtype=torch.bool)
        ring[..., out : out + x.shape[-2], out : out + x.shape[-1]] = False
        assert bool(got[0][ring].isnan().all()) and bool(got[3][ring].isnan().all())
        fit = ~want[0].isnan()  # g_x, g_y: only where m is a number (they skip the centre line)
        assert bool((fit == ~want[3].isnan()).all()) and bool((~fit).any())
        for g, w in zip(got, want, strict=True):
            inner = g[..., out : out + x.shape[-2], out : out + x.shape[-1]]
            torch.testing.assert_close(inner[fit], w[fit], rtol=1e-9, atol=1e-12)
        for k in (0, 3):
            assert bool(
                got[k][..., out : out + x.shape[-2], out : out + x.shape[-1]][~fit].isnan().all()
            )


def _between_by_loops(x, sigma, amp, tolerance, reach, share):
    """``z_b`` of the module docstring pixel by pixel in Python floats (the reference)."""
    h, w = x.shape[-2:]
    xs, h2 = x[0, 0].tolist(), (0.5 * sigma * sigma)[0, 0].tolist()
    am = None if amp is None else amp[0, 0].tolist()
    out = torch.full_like(x, -math.inf)
    for i in range(h):
        for j in range(w):
            if math.isnan(xs[i][j]):
                continue
            best = -math.inf
            for uy, ux in [(0, 1), (1, 0), (1, 1), (1, -1)]:
                sides = []
                for sign in (-1, 1):  # side a, side b
                    q = [(i + sign * k * uy, j + sign * k * ux) for k in range(1, reach + 1)]
                    sides.append([(a, b) for a, b in q if 0 <= a < h and 0 <= b < w])
                present = [[(a, b) for a, b in s if not math.isnan(xs[a][b])] for s in sides]

                def margin(pts, sgn, i=i, j=j):
                    vals = [
                        sgn * (xs[i][j] - xs[a][b]) / math.sqrt(h2[i][j] + h2[a][b]) for a, b in pts
                    ]
                    return max(vals, default=-math.inf)

                z = -math.inf
                for one, other in ((0, 1), (1, 0)):
                    lower, higher = margin(present[one], 1), margin(present[other], -1)
                    near = min([xs[a][b] for a, b in present[one]], default=math.inf)
                    far = max([xs[a][b] for a, b in present[other]], default=-math.inf)
                    gap = share * (far - near)
                    if xs[i][j] - near > gap and far - xs[i][j] > gap:
                        z = max(z, min(lower, higher))
                if am is not None:
                    line = [max(am[a][b], 0.0) for s in present for a, b in s]
                    if not am[i][j] <= (1.0 + tolerance) * max(line, default=0.0):
                        z = -math.inf
                best = max(best, z)
            out[0, 0, i, j] = best
    return out


@pytest.mark.parametrize("reach", [1, 3, 4])
def test_between_margin_equals_pixel_loops(reach):
    """The between test (shared pair differences, +-inf for absent pixels, extremes by doubling)
    equals a pixel-by-pixel loop over the lines, with holes, frame borders and the amplitude."""
    from tof_fpn_torch.runtime.flying import _between

    x = _holed_surface(10 + reach)
    g = torch.Generator().manual_seed(reach)
    sigma = 0.004 + 0.004 * torch.rand(x.shape, generator=g, dtype=torch.float64)
    amp = 50.0 + 100.0 * torch.rand(x.shape, generator=g, dtype=torch.float64)
    amp[0, 0, 5, 6] = -1.0
    valid = ~x.isnan()
    amp = torch.where(valid, amp, math.nan)  # as the stage passes it
    for a in (amp, None):
        got = _between(x, sigma, a, 0.1, reach, 0.03)
        want = _between_by_loops(x, sigma, a, 0.1, reach, 0.03)
        assert bool((want[valid] > 0).any()) and bool((want[valid] == -math.inf).any())
        torch.testing.assert_close(got[valid], want[valid], rtol=1e-12, atol=0)
