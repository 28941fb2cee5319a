"""The fixed pattern learned from a camera's frames of different scenes
(:func:`tof_fpn_torch.analysis.learn_folder_pattern`)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_fpn_torch.analysis import folder_pattern as fp
from tof_fpn_torch.analysis import learn_folder_pattern

H, W = 72, 96


def scene(rng: np.random.Generator) -> np.ndarray:
    """A piecewise-planar scene in metres: two planes meeting in a kink (a room corner seen at a
    random place and angle), plus a box with a depth edge; every pose different."""
    y, x = np.mgrid[0:H, 0:W].astype(float)
    x0 = rng.uniform(0.2, 0.8) * W
    base = rng.uniform(1.5, 3.0)
    s1, s2 = rng.uniform(-0.02, 0.02, 2)
    sy = rng.uniform(-0.01, 0.01)
    z = base + np.where(x < x0, s1 * (x - x0), s2 * (x - x0)) + sy * (y - H / 2)
    bx, by = rng.integers(0, W - 20), rng.integers(0, H - 20)
    z[by : by + 20, bx : bx + 20] -= rng.uniform(0.2, 0.6)
    return z


def folder(n: int, pattern: np.ndarray, noise_m: float, seed: int, still: bool = False):
    rng = np.random.default_rng(seed)
    first = scene(rng)
    truth = np.stack([first if still else scene(rng) for _ in range(n)])
    noisy = truth + pattern[None] + rng.normal(0, noise_m, truth.shape)
    return torch.from_numpy(noisy)[:, None], torch.from_numpy(truth)[:, None]


def columns(seed: int, sd: float) -> np.ndarray:
    c = np.random.default_rng(seed).normal(0, sd, W)
    return np.broadcast_to(c - c.mean(), (H, W)).copy()


def gain_db(noisy, truth, pattern_est) -> list[float]:
    out = []
    for i in range(noisy.shape[0]):
        e_in = (noisy[i, 0] - truth[i, 0]).numpy()
        e_out = e_in - pattern_est
        out.append(20 * math.log10(np.sqrt(np.mean(e_in**2)) / np.sqrt(np.mean(e_out**2))))
    return out


def test_column_offsets_are_learned_from_different_scenes():
    pattern = columns(1, 0.003)
    d, t = folder(8, pattern, 0.002, seed=2)
    learned = learn_folder_pattern(d)
    assert learned.pattern is not None, learned.reason
    assert learned.scenes == 8
    est = learned.pattern.offset_map().numpy()
    assert np.corrcoef(est.ravel(), pattern.ravel())[0, 1] > 0.95
    # the oracle gains 20 log10(sqrt(3^2 + 2^2) / 2) = 5.1 dB per frame
    gains = gain_db(d, t, est)
    assert min(gains) > 3.5, gains
    assert learned.parts["columns"]["factor"] > 0.9
    assert learned.parts["pixels"]["factor"] == 0.0  # none there: not applied
    assert "columns" in learned.summary() and "8 scenes" in learned.summary()


def test_the_column_offsets_low_frequencies_are_learned_too():
    """White column offsets: their low frequencies are where a scene's slopes hide them from
    second differences between neighbours; third differences at a wider gap see them. Every
    frame comes within 0.6 dB of the oracle (with second differences alone: 0.92 dB short)."""
    pattern = columns(3, 0.003)
    d, t = folder(8, pattern, 0.002, seed=4)
    learned = learn_folder_pattern(d)
    assert learned.pattern is not None, learned.reason
    gains = np.array(gain_db(d, t, learned.pattern.offset_map().numpy()))
    oracle = np.array(gain_db(d, t, pattern))
    assert (oracle - gains).max() < 0.6, (gains, oracle)


def test_a_per_pixel_map_is_learned():
    rng = np.random.default_rng(5)
    pattern = rng.normal(0, 0.003, (H, W))
    pattern -= pattern.mean()
    d, t = folder(8, pattern, 0.002, seed=6)
    learned = learn_folder_pattern(d)
    assert learned.pattern is not None, learned.reason
    assert learned.parts["pixels"]["factor"] > 0.5
    gains = gain_db(d, t, learned.pattern.offset_map().numpy())
    assert min(gains) > 2.0, gains


def test_no_pattern_learns_nothing_and_says_why():
    d, _ = folder(8, np.zeros((H, W)), 0.002, seed=3)
    learned = learn_folder_pattern(d)
    assert learned.pattern is None
    assert "halves" in learned.reason
    assert "no fixed pattern learned from 8 frame(s)" in learned.summary()


def test_a_still_scene_is_not_taken_for_a_pattern():
    d, _ = folder(8, columns(1, 0.003), 0.002, seed=4, still=True)
    learned = learn_folder_pattern(d)
    assert learned.pattern is None
    assert learned.scenes == 1
    assert "still scene" in learned.reason


def test_invalid_pixels_are_left_out():
    pattern = columns(7, 0.003)
    d, t = folder(8, pattern, 0.002, seed=8)
    whole = learn_folder_pattern(d).pattern.offset_map().numpy()
    holes = torch.rand(d.shape, generator=torch.Generator().manual_seed(0)) < 0.05
    d = d.clone()
    d[:4][holes[:4]] = 0.0
    d[4:][holes[4:]] = float("nan")
    learned = learn_folder_pattern(d)
    assert learned.pattern is not None
    est = learned.pattern.offset_map().numpy()
    assert np.isfinite(est).all()
    # 5 % holes (a hole takes three second differences per axis with it) cost little
    corr = [np.corrcoef(e.ravel(), pattern.ravel())[0, 1] for e in (est, whole)]
    assert corr[0] > 0.88 and corr[0] > corr[1] - 0.02, corr


def test_the_noise_model_follows_one_over_amplitude():
    """Depth noise ``k / A`` (low sensing): the per-frame ``k`` is found from the frame itself,
    edges and all."""
    rng = np.random.default_rng(10)
    truth = np.stack([scene(rng) for _ in range(3)]) * 1000  # mm
    amp = rng.uniform(20, 400, truth.shape)
    k = np.array([400.0, 800.0, 1600.0])[:, None, None]
    noisy = torch.from_numpy(truth + rng.normal(0, 1.0, truth.shape) * k / amp)
    var = fp._noise_var(noisy, torch.from_numpy(amp)).numpy()
    k_est = np.sqrt(var * amp**2)[:, 0, 0]
    np.testing.assert_allclose(k_est, k[:, 0, 0], rtol=0.1)
    # without amplitudes: one level per frame
    flat = fp._noise_var(noisy, None).numpy()
    assert np.ptp(flat[0]) == 0 and flat[2, 0, 0] > 3 * flat[0, 0, 0]


@pytest.mark.parametrize("channels", [1, 3])
def test_the_column_model_solves_the_least_squares_problem(channels):
    """The first (least-squares) iteration of the column model, offsets alone (1 channel) or with
    a read-out's two more channels (3), against NumPy's lstsq of the same objective written out
    row by row: second differences at gap 1 and third differences at gap 4."""
    rng = np.random.default_rng(11)
    n, h, w = 3, 5, 17  # odd: torch.median and np.median agree
    d = torch.from_numpy(rng.normal(0, 1, (n, h, w)))
    var = torch.from_numpy(rng.uniform(0.5, 2, (n, h, w)))
    basis = torch.from_numpy(rng.normal(0, 1, (channels, n, h, w)))
    basis[0] = 1.0
    got, _ = fp._columns(fp._column_terms(d, var, basis, (1, 4)), iterations=1)
    dn, vn, b = d.numpy(), var.numpy(), basis.numpy()
    rows, rhs = [], []
    for gap, kernel in ((1, (1.0, -2.0, 1.0)), (4, (1.0, -3.0, 3.0, -1.0))):
        span = (len(kernel) - 1) * gap
        for i in range(n):
            for y in range(h):
                for x in range(w - span):
                    at = [x + k * gap for k in range(len(kernel))]
                    e = sum(c * dn[i, y, j] for c, j in zip(kernel, at, strict=True))
                    s2 = sum(c * c * vn[i, y, j] for c, j in zip(kernel, at, strict=True))
                    row = np.zeros(channels * w)
                    for c, j in zip(kernel, at, strict=True):
                        for a in range(channels):
                            row[a * w + j] += c * b[a, i, y, j]
                    rows.append(row / np.sqrt(s2))
                    rhs.append(e / np.sqrt(s2))
    rows = np.array(rows)
    lam = 1e-2 * float(np.median(np.diag(rows.T @ rows)[:w]))
    a = np.vstack([rows, np.sqrt(lam) * np.eye(channels * w)])
    want = np.linalg.lstsq(a, np.concatenate([rhs, np.zeros(channels * w)]), rcond=None)[0]
    want = want.reshape(channels, w)
    np.testing.assert_allclose(got.numpy(), want - want.mean(1, keepdims=True), atol=1e-10)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(depth=torch.ones(3, 4, 4)), "depth must be a"),
        (dict(depth=torch.ones(3, 1, 4, 4, dtype=torch.int32)), "floating point"),
        (dict(depth=torch.ones(3, 1, 4, 4), amplitude=torch.ones(3, 1, 4, 5)), "amplitude"),
        (dict(depth=torch.ones(3, 1, 4, 4), min_scenes=1), "min_scenes"),
        (dict(depth=torch.ones(3, 1, 4, 4), min_z=0), "min_z"),
    ],
)
def test_bad_arguments_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        learn_folder_pattern(**kwargs)


def test_tiny_frames_learn_nothing():
    learned = learn_folder_pattern(torch.rand(6, 1, 2, 50) + 1)
    assert learned.pattern is None and "too small" in learned.reason


@pytest.mark.parametrize("gap", [1, 4])
@pytest.mark.parametrize("dim", [-1, -2])
def test_the_difference_adjoint_is_its_transpose(dim, gap):
    """<D x, e> = <x, D^T e>, and ``squared`` gives the diagonal of D^T diag(e) D (the second
    difference at gap 1, the third at gap 4), checked on unit vectors."""
    g = torch.Generator().manual_seed(4)
    x = torch.randn(2, 15, 17, generator=g, dtype=torch.float64)
    e = torch.randn(fp._diff(x, dim, gap).shape, generator=g, dtype=torch.float64)
    n = x.shape[dim]
    assert torch.allclose((fp._diff(x, dim, gap) * e).sum(), (x * fp._diff_t(e, dim, n, gap)).sum())
    w = torch.rand(fp._diff(x, dim, gap).shape, generator=g, dtype=torch.float64)
    diag = fp._diff_t(w, dim, n, gap, squared=True)
    for idx in [(0, 3, 4), (1, 0, 0), (1, 14, 16), (0, 7, 8)]:
        unit = torch.zeros_like(x)
        unit[idx] = 1.0
        d = fp._diff(unit, dim, gap)
        assert torch.allclose(diag[idx], (w * d * d).sum())
    # the kernels themselves: a second difference at gap 1, a third at gap 4
    ramp = torch.arange(17, dtype=torch.float64)
    assert torch.equal(fp._diff(ramp**2, -1, 1), torch.full((15,), 2.0, dtype=torch.float64))
    assert torch.allclose(fp._diff(ramp**2, -1, 4), torch.zeros(5, dtype=torch.float64))
    assert torch.allclose(
        fp._diff(ramp**3, -1, 4), torch.full((5,), -6.0 * 64, dtype=torch.float64)
    )


@pytest.mark.parametrize(("h", "w"), [(8, 9), (200, 8), (9, 400), (17, 23)])
@pytest.mark.parametrize("holes", [0.3, 0.95])
@pytest.mark.parametrize("with_amplitude", [True, False])
def test_small_frames_and_frames_mostly_holes_never_fail(h, w, holes, with_amplitude):
    """Columns or rows without a valid pixel, frames nearly empty: the estimate is finite or
    nothing, never an error (a singular system is no pattern)."""
    rng = np.random.default_rng(h * w)
    x = np.arange(w) / w
    d = 1.5 + rng.uniform(0, 1, (6, 1, 1, 1)) + rng.uniform(-0.5, 0.5, (6, 1, 1, 1)) * x
    d = d + 0.002 * rng.normal(size=(6, 1, h, w)) + 0.004 * rng.normal(size=w)
    d[rng.uniform(size=d.shape) < holes] = np.nan
    d[:, :, :, : w // 2 + 1] = np.nan  # over half the columns never seen
    amp = torch.from_numpy(rng.uniform(10, 300, d.shape)) if with_amplitude else None
    learned = learn_folder_pattern(torch.from_numpy(d), amp)
    if learned.pattern is not None:
        assert torch.isfinite(learned.pattern.offset_map()).all()
    else:
        assert learned.reason


def test_frames_under_eight_a_side_learn_nothing():
    learned = learn_folder_pattern(torch.rand(6, 1, 7, 50, dtype=torch.float64) + 1)
    assert learned.pattern is None and "too small (< 8 a side)" in learned.reason


def readout_folder(n: int, fov_deg: float, seed: int):
    """Frames of a camera that writes depth Z along its axis (pinhole, ``fov_deg`` horizontal)
    with a complex column read-out offset ``c(x)`` added to ``A e^{j phi}``, ``phi`` the phase of
    the radial distance ``Z |ray|`` at 20 MHz; noise ``~ 1 / A``."""
    from tof_fpn_torch.runtime._phasor import metres_per_radian

    rng = np.random.default_rng(seed)
    scale = metres_per_radian(20e6)
    f_px = (W / 2) / math.tan(math.radians(fov_deg) / 2)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    ray = np.sqrt(1 + ((xx - (W - 1) / 2) ** 2 + (yy - (H - 1) / 2) ** 2) / f_px**2)
    c = rng.normal(0, 0.5, W) + 1j * rng.normal(0, 0.5, W)
    c -= c.mean()
    truth, meas, amps = [], [], []
    for _ in range(n):
        z_true = scene(rng) + rng.uniform(0, 1.5)  # phases over much of the range, no wrap
        a = rng.uniform(25, 80) * (1 + 0.5 * np.sin(xx / rng.uniform(8, 20) + rng.uniform(0, 6)))
        zc = a * np.exp(1j * z_true * ray / scale) + c[None, :]
        phase = np.mod(np.angle(zc), 2 * np.pi)
        meas.append(phase * scale / ray + rng.normal(0, 0.03 / a))  # 0.6-2.4 mm noise
        truth.append(z_true)
        amps.append(np.abs(zc))
    as_t = lambda v: torch.from_numpy(np.stack(v))[:, None]  # noqa: E731
    return as_t(meas), as_t(truth), as_t(amps)


def test_a_read_out_offset_of_a_camera_writing_z_is_learned_on_the_radial_distance(monkeypatch):
    d, t, a = readout_folder(8, 70.0, seed=5)
    learned = learn_folder_pattern(d, a)
    assert learned.readout is not None, learned.summary()
    assert learned.evidence["frequency_hz"] == 20e6
    assert learned.evidence["field_of_view_deg"] == 70.0
    assert "70 degree field" in learned.summary()
    f_px = learned.readout.focal_length_px
    assert f_px == pytest.approx((W / 2) / math.tan(math.radians(35.0)))

    def gain(lp) -> float:
        out = lp.module()(d, a)
        e_in, e_out = (d - t).pow(2).mean(), (out - t).pow(2).mean()
        return 10 * math.log10(float(e_in / e_out))

    g = gain(learned)
    # the same folder read as radial distances: the phases at the sides are wrong
    monkeypatch.setattr(fp, "FIELDS_OF_VIEW_DEG", (None,))
    radial = learn_folder_pattern(d, a)
    assert g > 6.0 and g > gain(radial) + 0.3, (g, gain(radial))
    # the focal length survives the pattern file's arrays
    back = type(learned).from_arrays(*learned.to_arrays())
    assert back.readout.focal_length_px == pytest.approx(f_px)
    torch.testing.assert_close(back.module()(d, a), learned.module()(d, a))


def cylinders(rng: np.random.Generator) -> np.ndarray:
    """A wall with two upright cylinders at random places: curved along x, the same in every row,
    so inside one frame their curvature looks just like a column pattern."""
    y, x = np.mgrid[0:H, 0:W].astype(float)
    z = np.full((H, W), rng.uniform(1.5, 3.0)) + rng.uniform(-0.01, 0.01) * (x - W / 2)
    for _ in range(2):
        x0, r = rng.uniform(0, W), rng.uniform(10, 30)
        bulge = np.sqrt(np.clip(1 - ((x - x0) / r) ** 2, 0, 1))
        z = np.where(np.abs(x - x0) < r, z - rng.uniform(0.1, 0.4) * bulge, z)
    return z


@pytest.mark.parametrize("seed", [3, 4])
def test_the_scenes_curvature_does_not_leak_into_the_columns_low_frequencies(seed):
    """Periodic column stripes over frames of curved scenes: the curvature the halves of the
    scenes do not share is shrunk band by band, so the estimate's error below a quarter of the
    Nyquist frequency stays under 0.2 mm RMS (one Wiener factor for the whole profile: 0.8-1.1
    mm)."""
    rng = np.random.default_rng(seed)
    x = np.arange(W)
    s = 0.8 * np.cos(2 * np.pi * x / 3 + rng.uniform(0, 6)) + 0.6 * np.cos(np.pi * x)
    pattern = np.broadcast_to((s - s.mean()) / s.std() * 0.002, (H, W))
    truth = np.stack([cylinders(rng) for _ in range(8)])
    noisy = torch.from_numpy(truth + pattern[None] + rng.normal(0, 0.002, truth.shape))[:, None]
    learned = learn_folder_pattern(noisy)
    assert learned.pattern is not None, learned.reason
    err = (learned.pattern.offset_map().numpy() - pattern).mean(0)
    spec = np.fft.rfft(err)
    spec[len(spec) // 4 :] = 0
    low = np.fft.irfft(spec, n=W)
    assert np.sqrt(np.mean(low**2)) < 2e-4, np.sqrt(np.mean(low**2))


def test_the_bands_sum_to_the_profile_and_hold_enough_frequencies():
    theta = torch.from_numpy(np.random.default_rng(0).normal(size=(3, 160)))
    bands = fp._bands(theta)
    assert len(bands) == 4  # 81 frequencies: [0, 5) joins [5, 10), then 10, 20, 41
    torch.testing.assert_close(sum(bands), theta)
    for b in bands:
        spec = torch.fft.rfft(b, dim=-1).abs().amax(0)
        assert int((spec > 1e-9).sum()) >= fp.BAND_MIN_BINS
    # disjoint bands: orthogonal
    assert abs(float((bands[0] * bands[1]).sum())) < 1e-9
    assert len(fp._bands(theta[:, :12])) == 1  # too few frequencies to split
