"""The camera-folder generator of the benchmarks (benchmarks/camera_folders.py)."""

from __future__ import annotations

import camera_folders as cf
import numpy as np
import pytest

from tof_fpn_torch.io import read_pair

H, W = 33, 47  # small and odd: fast


def _make(tmp_path, family="boxes", pattern="columns", seed=3, n=3, name="f"):
    return cf.make_folder(tmp_path / name, family, pattern, seed, n_frames=n, height=H, width=W)


def _clean(t):
    """Valid, non-mixed pixels: where observed = depth + pattern_frames + noise."""
    return t["valid"] & ~t["flying"]


def test_seeded_determinism(tmp_path):
    a = _make(tmp_path, "staircase", "stripes", seed=5, name="a")
    b = _make(tmp_path, "staircase", "stripes", seed=5, name="b")
    c = _make(tmp_path, "staircase", "stripes", seed=6, name="c")
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for stem in a["stems"]:
        for suffix in ("_depth.png", "_amplitude.png"):
            pa = (tmp_path / "a" / "frames" / f"{stem}{suffix}").read_bytes()
            pb = (tmp_path / "b" / "frames" / f"{stem}{suffix}").read_bytes()
            assert pa == pb
    assert not np.array_equal(np.nan_to_num(a["depth"]), np.nan_to_num(c["depth"]))
    assert not np.array_equal(a["pattern"], c["pattern"])


def test_folder_layout_and_saved_truth(tmp_path):
    t = _make(tmp_path, n=2)
    names = sorted(p.name for p in (tmp_path / "f" / "frames").iterdir())
    assert names == [
        "frame_000_amplitude.png",
        "frame_000_depth.png",
        "frame_001_amplitude.png",
        "frame_001_depth.png",
    ]
    saved = cf.load_truth(tmp_path / "f")
    for k in ("depth", "amplitude", "sd", "pattern", "pattern_frames", "observed", "valid"):
        np.testing.assert_array_equal(saved[k], t[k], err_msg=k)
    assert t["depth"].shape == (2, H, W) and t["pattern"].shape == (H, W)


@pytest.mark.parametrize("family", ["room_corner", "cylinders"])
def test_pngs_read_back_equal_the_truth_within_quantisation(tmp_path, family):
    t = _make(tmp_path, family, "complex_offset", seed=11)
    assert t["valid"].mean() > 0.5
    for i, stem in enumerate(t["stems"]):
        frames = tmp_path / "f" / "frames"
        depth, amp = read_pair(frames / f"{stem}_depth.png", frames / f"{stem}_amplitude.png")
        depth, amp = depth[0, 0].double().numpy(), amp[0, 0].double().numpy()
        np.testing.assert_array_equal(np.isfinite(depth), t["valid"][i])
        v = t["valid"][i]
        err = np.abs(depth[v] - t["observed"][i][v])
        assert err.max() <= 0.0005 + 1e-9
        # the measured amplitude: the true one plus noise of sd (sd_depth / m_per_rad) A
        m_per_rad = cf.C_LIGHT / (4 * np.pi * float(t["f_mod"]))
        a = t["amplitude"][i][v]
        z = (amp[v] - a) / (t["sd"][i][v] / m_per_rad * a)
        assert np.abs(z.mean()) < 0.5 and 0.5 < z.std() < 2.0
        assert amp[v].min() >= float(t["a_min"]) - 0.5


@pytest.mark.parametrize("kind", ["columns", "stripes", "rows", "kinect_p0"])
def test_additive_pattern_is_fixed_and_in_every_frame(tmp_path, kind):
    t = _make(tmp_path, "slanted_planes", kind, seed=2)
    p = t["pattern"]
    assert np.abs(p).max() > 1e-4
    for i in range(t["depth"].shape[0]):
        np.testing.assert_array_equal(t["pattern_frames"][i], p)
        m = _clean(t)[i]
        resid = t["observed"][i] - t["depth"][i] - t["noise"][i]
        np.testing.assert_allclose(resid[m], p[m], atol=1e-9)


def test_no_pattern_for_none(tmp_path):
    t = _make(tmp_path, "boxes", "none", seed=4)
    assert not t["pattern"].any() and not t["pattern_frames"].any() and not t["offset"].any()
    assert float(t["pattern_rms"]) == 0.0
    m = _clean(t)
    resid = t["observed"] - t["depth"] - t["noise"]
    assert np.abs(resid[m]).max() < 1e-9


@pytest.mark.parametrize("kind", cf.COMPLEX_KINDS)
def test_complex_offset_follows_the_phasor_formula(tmp_path, kind):
    t = _make(tmp_path, "cylinders", kind, seed=9, n=4)
    c, f = t["offset"], float(t["f_mod"])
    m_per_rad = cf.C_LIGHT / (4 * np.pi * f)
    for i in range(4):
        m = _clean(t)[i]
        a, zt = t["amplitude"][i], t["depth"][i]
        phi = 4 * np.pi * f * zt * t["ray_norm"] / cf.C_LIGHT
        zmeas = a * np.exp(1j * phi) + c  # z = A e^{j phi} + c
        depth_meas = (np.angle(zmeas * np.exp(-1j * phi)) + phi) * m_per_rad / t["ray_norm"]
        np.testing.assert_allclose(t["pattern_frames"][i][m], (depth_meas - zt)[m], atol=1e-9)
        resid = t["observed"][i] - zt - t["noise"][i]
        np.testing.assert_allclose(resid[m], (depth_meas - zt)[m], atol=1e-9)
    # the effect scales like 1 / A: times A / A_ref its RMS is the stated one
    m = _clean(t)
    scaled = t["pattern_frames"][m] * t["amplitude"][m] * np.broadcast_to(t["ray_norm"], m.shape)[m]
    rms = np.sqrt(np.mean((scaled / cf.A_REF) ** 2))
    assert rms == pytest.approx(float(t["pattern_rms"]), rel=0.25)


@pytest.mark.parametrize("kind", cf.PATTERNS)
def test_each_pattern_has_its_stated_rms(tmp_path, kind):
    for seed in (1, 2):
        t = _make(tmp_path, "textured", kind, seed=seed, n=1, name=f"s{seed}")
        rms = float(t["pattern_rms"])
        if kind == "none":
            assert rms == 0.0
            continue
        lo, hi = cf.RMS_RANGE[kind]
        assert lo <= rms <= hi
        if kind in cf.COMPLEX_KINDS:
            m_per_rad = cf.C_LIGHT / (4 * np.pi * float(t["f_mod"]))
            got = m_per_rad * np.sqrt(np.mean(np.abs(t["offset"]) ** 2)) / (np.sqrt(2) * cf.A_REF)
        else:
            got = np.sqrt(np.mean(t["pattern"] ** 2))
            assert abs(t["pattern"].mean()) < 1e-12
        assert got == pytest.approx(rms, rel=1e-9)


def test_pattern_structures(tmp_path):
    col = _make(tmp_path, "boxes", "columns", n=1, name="c")["pattern"]
    assert np.ptp(col, axis=0).max() == 0 and np.ptp(col, axis=1).min() > 0
    row = _make(tmp_path, "boxes", "rows", n=1, name="r")["pattern"]
    assert np.ptp(row, axis=1).max() == 0 and np.ptp(row, axis=0).min() > 0
    st = _make(tmp_path, "boxes", "stripes", n=1, name="s")["pattern"][0]
    x = np.arange(W)
    w3 = 2 * np.pi * x / 3  # frequencies 2 pi / 3 and pi (radians per pixel) and a constant
    basis = np.stack([np.cos(w3), np.sin(w3), np.cos(np.pi * x), np.ones(W)], 1)
    coef = np.linalg.lstsq(basis, st, rcond=None)[0]
    np.testing.assert_allclose(basis @ coef, st, atol=1e-12)
    assert np.hypot(coef[0], coef[1]) > 1e-4 and abs(coef[2]) > 1e-4
    lo = _make(tmp_path, "boxes", "stripes_low_a", n=1, name="l")["offset"]
    assert np.ptp(lo, axis=0).max() == 0
    coef = np.linalg.lstsq(basis.astype(complex), lo[0], rcond=None)[0]
    np.testing.assert_allclose(basis @ coef, lo[0], atol=1e-9)
    kin = _make(tmp_path, "boxes", "kinect_p0", n=1, name="k")["pattern"]
    # a per-pixel map: neither constant along the columns nor along the rows
    assert np.ptp(kin, axis=0).min() > 0 and np.ptp(kin, axis=1).min() > 0


def test_still_family_has_one_scene(tmp_path):
    t = _make(tmp_path, "still", "stripes", seed=7, n=3)
    for i in (1, 2):
        np.testing.assert_array_equal(t["depth"][i], t["depth"][0])
        np.testing.assert_array_equal(t["amplitude"][i], t["amplitude"][0])
        assert not np.array_equal(t["noise"][i], t["noise"][0])
    moving = _make(tmp_path, "boxes", "stripes", seed=7, n=2, name="m")
    assert not np.array_equal(np.nan_to_num(moving["depth"][1]), np.nan_to_num(moving["depth"][0]))


def test_noise_is_k_over_amplitude_and_low_signal_is_invalid(tmp_path):
    t = _make(tmp_path, "room_corner", "none", seed=12, n=2)
    a, sd, b = t["amplitude"], t["sd"], float(t["background"])
    hit = np.isfinite(t["depth"])
    k = sd[hit] * a[hit] / np.sqrt(a[hit] + b)
    np.testing.assert_allclose(k, k[0], rtol=1e-9)
    assert 0.5e-3 < np.nanmedian(sd) < 20e-3
    assert not t["valid"][~hit].any()


def test_split_is_disjoint():
    dev = {s for s in range(0, 3000) if cf.split(s) == "dev"}
    held = {s for s in range(0, 3000) if cf.split(s) == "held_out"}
    assert dev and held and not dev & held and len(dev | held) == 3000
    assert max(dev) < min(held) == cf.HELD_OUT_START
    with pytest.raises(ValueError):
        cf.split(-1)


def test_cli_writes_one_folder(tmp_path):
    out = tmp_path / "one"
    args = ["--family", "textured", "--pattern", "rows", "--seed", "1", "--frames", "2"]
    assert cf.main([str(out), *args, "--height", "24", "--width", "31"]) == 0
    t = cf.load_truth(out)
    assert t["depth"].shape == (2, 24, 31) and str(t["pattern_kind"]) == "rows"
    assert len(list((out / "frames").glob("*_depth.png"))) == 2
