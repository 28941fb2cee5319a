"""The second held-out part of the literature generator (benchmarks/literature_heldout2.py), without
any diagnosis: shapes, validity, every planted form changing the raw samples the way its docstring
says, effect-free nulls, determinism, and that its forms differ from the dev and held-out ones."""

from __future__ import annotations

import bench_literature as bl
import literature_generator as lg
import literature_heldout as lh
import literature_heldout2 as l2
import numpy as np
import pytest
from scipy import ndimage
from test_literature_generator import check_recording

SIZE = (36, 48, 6)
NEW = [(f, fo) for f in l2.HELDOUT2_FORMS for fo in l2.HELDOUT2_FORMS[f]]


def _ctx(seed=0, scene="aisle", size=SIZE):
    rng = np.random.default_rng(seed)
    spec = l2.HELDOUT2_SCENES[scene](rng)
    return lg.make_ctx(spec, *size, rng)


def _nl(ctx, plan):
    """Noiseless render: raw, depth, amplitude."""
    return lg.render(ctx, plan, None)


def _build(builder, ctx, seed=1):
    return builder(ctx, np.random.default_rng(seed))


def _plan(builder, ctx, seed=1):
    return _build(builder, ctx, seed)[0]


# ---- the recordings ----------------------------------------------------------------------------


@pytest.mark.parametrize("family,form", NEW + [("none", "null")])
def test_shapes_dtypes_meta_and_nan_only_where_invalid(family, form):
    r = l2.generate(family, form, l2.SEED0 + 3, SIZE)
    check_recording(r, SIZE, 0.3)
    tr = r["truth"]
    assert (tr["family"], tr["form"], tr["part"]) == (family, form, "heldout2")
    assert tr["scene"] in l2.HELDOUT2_SCENES
    if family != "none":
        st = tr["stats"]
        assert tr["citation"] and st["affected_fraction"] > 0
        # the size against the camera noise is stated and the effect is visible
        assert st["noise_reference"] in ("per-frame", "temporal-mean")
        assert st["visibility"] > 2.0, st


def test_every_scene_is_closed_within_the_range():
    for name, make in l2.HELDOUT2_SCENES.items():
        for seed in range(4):
            ctx = lg.make_ctx(
                make(np.random.default_rng(seed)), 30, 40, 1, np.random.default_rng(0)
            )
            r = ctx.geom["r"]
            assert np.isfinite(r).all() and 0.3 < r.min() and r.max() < 6.0, name
            assert np.ptp(r) > 1.0, name  # depth steps and a far wall


def test_null_is_effect_free():
    r = l2.generate("none", "null", l2.SEED0 + 11, (60, 80, 24))
    assert "stats" not in r["truth"] and r["truth"]["magnitude"] == 0.0
    assert r["meta"]["integration_time_us"] == lg.BASE_INTEGRATION_US
    assert r["raw"].max() < lg.ADC_MAX
    assert (r["raw"] - lg.BLACK_DN).max() < lg.CONV_GAIN * lg.FULL_WELL
    err = np.nanmean(r["depth"], axis=0) - r["scene_depth"]
    sd = np.nanstd(r["depth"], axis=0) / np.sqrt(24)
    z = err / sd
    assert abs(np.nanmedian(z)) < 0.2 and np.nanmean(np.abs(z) > 4) < 0.01
    for scene in l2.HELDOUT2_SCENES:  # the noiseless null renders every new scene exactly
        ctx = _ctx(11, scene, (30, 40, 2))
        _, d, _ = _nl(ctx, lg.Plan())
        assert np.abs(d - ctx.geom["r"]).max() < 1e-9


@pytest.mark.parametrize(
    "family,form",
    [
        ("impulsive_pixels", "adc_sparkle_codes"),
        ("temporal_drift", "phase_random_walk"),
        ("noise_floor", "source_intensity_noise"),
        ("saturation", "ambient_full_well"),
        ("none", "null"),
    ],
)
def test_deterministic_per_seed(family, form):
    a = l2.generate(family, form, l2.SEED0 + 5, SIZE)
    b = l2.generate(family, form, l2.SEED0 + 5, SIZE)
    c = l2.generate(family, form, l2.SEED0 + 6, SIZE)
    for k in ("depth", "amplitude", "raw", "scene_depth"):
        np.testing.assert_array_equal(a[k], b[k])
    assert not np.array_equal(a["raw"], c["raw"])
    assert a["truth"] == b["truth"]


def test_the_seed_stream_differs_from_the_other_parts():
    a = l2.generate("none", "null", 7, SIZE)
    b = lh.generate("none", "null", 7, SIZE)
    c = lg.generate("none", "null", 7, SIZE)
    assert not np.array_equal(a["raw"], b["raw"]) and not np.array_equal(a["raw"], c["raw"])


# ---- new forms, not the old ones -------------------------------------------------------------


def test_new_forms_cover_every_family_and_differ_from_dev_and_heldout_by_name():
    assert set(l2.HELDOUT2_FORMS) == set(lg.DEV_FORMS) == set(lh.HELDOUT_FORMS)
    for fam in l2.HELDOUT2_FORMS:
        new = l2.HELDOUT2_FORMS[fam]
        assert len(new) >= 2, fam
        assert not set(new) & (set(lg.DEV_FORMS[fam]) | set(lh.HELDOUT_FORMS[fam])), fam
        old = list(lg.DEV_FORMS[fam].values()) + list(lh.HELDOUT_FORMS[fam].values())
        assert set(new.values()).isdisjoint(old)
        assert all(f.__module__ == "literature_heldout2" for f in new.values())
        assert all(f.__doc__ and len(f.__doc__) > 200 for f in new.values())  # cited
    assert not set(l2.HELDOUT2_SCENES) & (set(lg.DEV_SCENES) | set(lh.HELDOUT_SCENES))
    last_heldout = lg.cases(lh.HELDOUT_FORMS, 50, 200, lh.SEED0)[-1][2]
    assert last_heldout < l2.SEED0


def _raw_change(builder, ctx, seed):
    """The form's raw change beyond a plain change of the exposure or the conversion gain."""
    plan = _plan(builder, ctx, seed)
    raw0, _, _ = _nl(ctx, lg.Plan(exposure=plan.exposure, conv_gain=plan.conv_gain))
    raw1, _, _ = _nl(ctx, plan)
    d = raw1 - raw0
    if not plan.temporal:
        d = d.mean(axis=0)
    return d.ravel()


@pytest.mark.parametrize("family", sorted(l2.HELDOUT2_FORMS))
def test_new_forms_change_the_raw_samples_unlike_the_old_forms_on_the_same_scene(family):
    """On one scene, the raw change of every new form is not a rescaled copy of the raw change
    of any dev or held-out form of its family: the best scale-and-offset fit of the old form's
    change misses the new one's by more than 2 % of its largest value somewhere."""
    ctx = _ctx(21, "doorway", (30, 40, 3))
    old = {**lg.DEV_FORMS[family], **lh.HELDOUT_FORMS[family]}
    for name, b in l2.HELDOUT2_FORMS[family].items():
        dn = _raw_change(b, ctx, 3)
        assert np.abs(dn).max() > 1.0, name
        for oname, ob in old.items():
            if oname == "kinect_p0":
                continue  # needs the real P0 file; its pattern is a real sensor's, compared below
            do = _raw_change(ob, ctx, 3)
            if dn.shape != do.shape or np.std(do) == 0:
                continue
            x = np.stack([do, np.ones_like(do)], 1)
            coef, *_ = np.linalg.lstsq(x, dn, rcond=None)
            res = np.abs(dn - x @ coef).max() / np.abs(dn).max()
            assert res > 0.02, (name, oname, res)


# ---- saturation ------------------------------------------------------------------------------


def test_column_adc_clip_clips_each_column_at_its_own_level():
    ctx = _ctx(2, "aisle")
    plan, p, _, size = _build(l2.sat_column_adc_clip, ctx, 0)
    level = plan.raw_hook(np.full((1, 4, ctx.h, ctx.w), 1e9))[0, 0, 0]
    assert level.min() == size["clip_level_min_dn"] and level.max() == size["clip_level_max_dn"]
    assert np.ptp(level) > 1000 and level.max() < lg.BLACK_DN + lg.CONV_GAIN * lg.FULL_WELL
    raw, _, _ = _nl(ctx, plan)
    assert np.all(raw <= level)
    at = np.isclose(raw, level)
    assert abs(at.mean() - p) < 0.01
    clipped_cols = np.nonzero(at.any(axis=(0, 1, 2)))[0]
    assert len(np.unique(level[clipped_cols])) > 1  # clipped at different levels
    r = l2.generate("saturation", "column_adc_clip", l2.SEED0 + 1, SIZE)
    assert r["raw"].max() < lg.ADC_MAX  # not at the common full scale


def test_ambient_full_well_clips_at_a_lower_active_level_where_the_sun_falls():
    ctx = _ctx(2, "doorway")
    plan, p, _, _ = _build(l2.sat_ambient_full_well, ctx, 0)
    raw, _, _ = _nl(ctx, plan)
    e = (raw - lg.BLACK_DN) / lg.CONV_GAIN
    assert e.max() <= lg.FULL_WELL + 1e-6
    full = np.isclose(e, lg.FULL_WELL)
    assert abs(full.mean() - p) < 0.01
    sun = np.asarray(plan.dark_extra)[0]
    pix = full.any(axis=(0, 1))
    # the same exposure without the ambient light clips far fewer samples
    raw_dark, _, _ = _nl(ctx, lg.Plan(exposure=plan.exposure))
    e_dark = (raw_dark - lg.BLACK_DN) / lg.CONV_GAIN
    assert np.isclose(e_dark, lg.FULL_WELL).mean() < 0.5 * p
    # not one threshold on the active light: some unclipped pixels get more active light than
    # some clipped ones, which have more ambient light than those unclipped pixels
    act = plan.exposure * ctx.e_act
    assert act[~pix].max() > act[pix].min()
    weak = pix & (act < act[~pix].max())
    assert sun[weak].min() > sun[~pix & (act > act[weak].max())].max()
    # partial clipping: many clipped pixels keep a sample below the well
    assert (~full.all(axis=1))[0][pix].mean() > 0.3


def test_differential_clip_limits_the_tap_differences_and_keeps_the_common_mode():
    ctx = _ctx(2, "desk")
    plan, p, _, size = _build(l2.sat_differential_clip, ctx, 0)
    raw0, _, a0 = _nl(ctx, lg.Plan())
    raw1, _, a1 = _nl(ctx, plan)
    lim = size["difference_limit_dn"]
    for a, b in ((0, 2), (1, 3)):
        assert np.all(np.abs(raw1[:, a] - raw1[:, b]) / 2 <= lim + 1e-9)
        np.testing.assert_allclose(raw1[:, a] + raw1[:, b], raw0[:, a] + raw0[:, b], atol=1e-9)
    at = np.stack([np.abs(raw1[:, 0] - raw1[:, 2]), np.abs(raw1[:, 1] - raw1[:, 3])]) / 2
    assert abs(np.isclose(at, lim).mean() - p) < 0.01
    assert a1.max() < a0.max()  # the amplitude stops growing


# ---- fixed pattern ---------------------------------------------------------------------------


@pytest.mark.parametrize("builder", [l2.fpn_ar_column_pixel, l2.fpn_emi_fringe])
def test_fpn_is_the_same_offset_in_every_frame(builder):
    ctx = _ctx(5, "aisle")
    raw0, _, _ = _nl(ctx, lg.Plan())
    raw1, _, _ = _nl(ctx, _plan(builder, ctx))
    diff = raw1 - raw0
    assert np.abs(diff).max() > 1.0
    np.testing.assert_allclose(diff, np.broadcast_to(diff[:1], diff.shape), atol=1e-9)
    r = l2.generate("fpn_pattern", "ar_column_pixel", l2.SEED0 + 2, (30, 40, 12))
    n = l2.generate("none", "null", l2.SEED0 + 2, (30, 40, 12))
    # the same scene and noise stream: the frame-to-frame noise is untouched by the pattern
    np.testing.assert_allclose(np.std(r["raw"] - n["raw"], axis=0), 0, atol=1.01)


def _lag1(x, axis):
    a = np.moveaxis(x, axis, 0)
    a = a - a.mean()
    return float(np.sum(a[1:] * a[:-1]) / np.sum(a * a))


def test_ar_fpn_is_spatially_correlated_along_rows_and_columns():
    ctx = _ctx(5, "desk", (60, 80, 2))
    off = np.asarray(_plan(l2.fpn_ar_column_pixel, ctx).offset_dn)
    for k in range(4):
        assert _lag1(off[k], 1) > 0.2 and _lag1(off[k], 0) > 0.05
        cols = off[k].mean(axis=0)
        assert np.std(cols) > 0.3 * np.std(off[k])  # a column component
    # a white DSNU (the dev form) has no such correlation
    white = np.asarray(_plan(lg.fpn_dsnu_tap_map, ctx).offset_dn)
    assert abs(_lag1(white[0] - white[0].mean(axis=0), 1)) < 0.1


def test_emi_fringe_is_one_tone_in_read_out_order():
    ctx = _ctx(5, "desk", (40, 60, 2))
    plan, _, _, size = _build(l2.fpn_emi_fringe, ctx)
    off = np.asarray(plan.offset_dn)
    for k in range(4):
        seq = off[k].ravel()  # row by row: the read-out order
        spec = np.abs(np.fft.rfft(seq)) ** 2
        top = int(np.argmax(spec))
        assert abs(top / len(seq) - size["cycles_per_pixel"]) < 2 / len(seq)
        assert spec[top - 2 : top + 3].sum() > 0.95 * spec.sum()
    assert not np.allclose(off[0], off[1])  # each tap its own read-out time


# ---- amplitude bias --------------------------------------------------------------------------


@pytest.mark.parametrize("builder", [l2.ab_bright_end, l2.ab_inverse_power])
def test_amplitude_bias_is_monotone_in_amplitude(builder):
    ctx = _ctx(7, "doorway")
    _, d0, _ = _nl(ctx, lg.Plan())
    plan, _, _, size = _build(builder, ctx)
    _, d1, _ = _nl(ctx, plan)
    bias = (d1 - d0)[0].ravel()
    order = np.argsort(ctx.amp0_dn.ravel())
    b = bias[order]
    step = np.diff(b)
    assert np.abs(b).max() > 0.01
    assert np.all(step <= 1e-9) or np.all(step >= -1e-9)
    if builder is l2.ab_bright_end:  # nothing below the threshold, the top few percent only
        a = ctx.amp0_dn.ravel()
        assert np.all(bias[a <= size["amplitude_threshold_dn"]] == 0)
        assert 0.02 < np.mean(bias != 0) < 0.11
    else:  # the weak end carries the bias, falling as a power law into the mid amplitudes
        a = ctx.amp0_dn.ravel()
        lo = np.abs(bias[a <= np.percentile(a, 2)]).min()
        mid = np.abs(bias[np.abs(a - np.median(a)) < 0.05 * np.median(a)]).mean()
        assert lo > 2 * mid > 0


# ---- cyclic error ------------------------------------------------------------------------


def _fit_share(err, basis):
    x = np.stack(basis + [np.ones_like(err)], 1)
    coef, *_ = np.linalg.lstsq(x, err, rcond=None)
    return 1 - np.var(err - x @ coef) / np.var(err)


def test_led_rc_pulse_wiggles_at_r_over_4_with_phase_shifted_harmonics():
    ctx = _ctx(8, "aisle")
    _, d, _ = _nl(ctx, _plan(l2.ce_led_rc_pulse, ctx))
    err = (d[0] - ctx.geom["r"]).ravel()
    phi = ctx.phi.ravel()
    assert np.abs(err).max() > 0.01
    full = [np.sin(4 * phi), np.cos(4 * phi), np.sin(8 * phi), np.cos(8 * phi)]
    assert _fit_share(err, full) > 0.95
    # the harmonics have their own phases: a pure odd-harmonic weighting (dev square wave or
    # triangle) gives an error in sin(4 phi), sin(8 phi) only; this one needs the cosines
    assert _fit_share(err, [np.sin(4 * phi), np.sin(8 * phi)]) < 0.8
    h = l2.rc_pulse_harmonics(0.5, 0.0)  # a square pulse through an ideal LED: real harmonics
    assert all(abs(v.imag) < 1e-12 for v in h.values()) and abs(h[3].real - 1 / 9) < 1e-9


def test_subframe_power_droop_errs_once_per_range_whatever_the_amplitude():
    ctx = _ctx(8, "doorway")
    _, d, _ = _nl(ctx, _plan(l2.ce_subframe_power_droop, ctx))
    err = (d[0] - ctx.geom["r"]).ravel()
    phi = ctx.phi.ravel()
    assert np.abs(err).max() > 0.01
    assert _fit_share(err, [np.sin(phi), np.cos(phi), np.sin(2 * phi), np.cos(2 * phi)]) > 0.99
    assert _fit_share(err, [np.sin(phi), np.cos(phi)]) > 0.8  # period R


# ---- gains, vignetting -----------------------------------------------------------------------


def test_demod_contrast_scales_the_amplitude_and_not_the_dc_or_the_depth():
    ctx = _ctx(9, "desk")
    raw0, d0, a0 = _nl(ctx, lg.Plan())
    raw1, d1, a1 = _nl(ctx, _plan(l2.pg_demod_contrast_map, ctx))
    np.testing.assert_allclose(d1, d0, atol=1e-9)
    np.testing.assert_allclose(raw1.mean(axis=1), raw0.mean(axis=1), rtol=1e-12)
    g = a1 / a0
    assert 0.02 < np.std(g) < 0.12
    np.testing.assert_allclose(g, np.broadcast_to(g[:1], g.shape), rtol=1e-6)  # fixed in time


@pytest.mark.parametrize(
    "builder", [l2.pg_nir_fringing, l2.vig_barrel_clip, l2.vig_flat_top_diffuser]
)
def test_gains_scale_the_amplitude_and_leave_the_depth(builder):
    ctx = _ctx(9, "aisle")
    plan = _plan(builder, ctx)
    _, d0, a0 = _nl(ctx, lg.Plan())
    _, d1, a1 = _nl(ctx, plan)
    np.testing.assert_allclose(d1, d0, atol=1e-9)
    g = np.asarray(plan.gain_light) * np.asarray(plan.gain_active)
    np.testing.assert_allclose(a1, a0 * g, rtol=1e-6)
    assert np.std(g) > 0.01 and g.max() <= 1.1 + 1e-9


def test_nir_fringes_are_contours_not_a_radial_falloff():
    ctx = _ctx(9, "aisle", (60, 80, 2))
    plan, a, _, _ = _build(l2.pg_nir_fringing, ctx)
    g = np.asarray(plan.gain_light)
    assert abs((g.max() - g.min()) / 2 - a) < 0.2 * a
    # several fringes across the image: the gain crosses 1 many times along a row
    crossings = np.count_nonzero(np.diff(np.sign(g - 1), axis=1))
    assert crossings > ctx.h
    ang = lg.field_angle(ctx).ravel()
    assert abs(np.corrcoef(ang, g.ravel())[0, 1]) < 0.5


def test_barrel_clip_is_flat_in_the_middle_and_falls_off_axis():
    ctx = _ctx(9, "aisle", (60, 80, 2))
    plan, loss, _, size = _build(l2.vig_barrel_clip, ctx)
    g = np.asarray(plan.gain_light)
    ang = lg.field_angle(ctx)
    assert np.allclose(g[ang < np.radians(size["onset_deg"]) - 1e-3], 1.0)
    order = np.argsort(ang.ravel())
    assert np.all(np.diff(g.ravel()[order]) <= 1e-12)
    assert abs((1 - g.min()) - loss) < 0.01
    # unlike the natural cos^n fall-off (dev), which already loses light at the onset angle
    cos4 = np.asarray(_plan(lg.vig_cos4, ctx).gain_light)
    onset = np.radians(size["onset_deg"])
    at = (ang < onset) & (ang > onset - np.radians(2.0))
    assert at.any() and cos4[at].max() < 0.99 and np.all(g[at] == 1.0)


def test_flat_top_diffuser_is_a_rectangular_profile_on_the_active_light():
    ctx = _ctx(9, "aisle", (60, 80, 2))
    plan = _plan(l2.vig_flat_top_diffuser, ctx)
    g = np.asarray(plan.gain_active)
    assert np.all(np.asarray(plan.gain_light) == 1.0)
    lg_ = np.log(g)  # separable: log g = f(x) + f(y)
    sep = lg_.mean(axis=1, keepdims=True) + lg_.mean(axis=0, keepdims=True) - lg_.mean()
    np.testing.assert_allclose(lg_, sep, atol=1e-9)
    assert g.max() > 0.97 and g.min() < 0.6


# ---- impulsive ---------------------------------------------------------------------------


def test_stuck_taps_hold_one_noiseless_code_in_every_frame():
    ctx = _ctx(10, "aisle")
    plan, f, _, size = _build(l2.imp_stuck_taps, ctx, 0)
    raw0, _, _ = _nl(ctx, lg.Plan())
    raw1, _, _ = _nl(ctx, plan)
    changed = np.abs(raw1 - raw0) > 1e-9
    pix = changed.any(axis=(0, 1))
    assert abs(pix.mean() - f) < 0.002 and pix.sum() == size["n_pixels"]
    assert changed.sum(axis=1)[0][pix].max() == 1  # one tap per pixel
    r = l2.generate("impulsive_pixels", "stuck_taps", l2.SEED0 + 4, (30, 40, 8))
    raw = r["raw"]
    const = (np.ptp(raw, axis=0) == 0).any(axis=0)  # a tap without any noise
    n = l2.generate("none", "null", l2.SEED0 + 4, (30, 40, 8))
    assert const.sum() >= 1 and (np.ptp(n["raw"], axis=0) == 0).any(axis=0).sum() == 0


def test_sparkle_codes_jump_by_a_power_of_two_in_random_places():
    ctx = _ctx(10, "aisle", (30, 40, 24))
    plan, _, _, size = _build(l2.imp_adc_sparkle_codes, ctx, 0)
    assert plan.temporal and size["events"] > 0
    raw0, _, _ = _nl(ctx, lg.Plan())
    raw1, _, _ = _nl(ctx, plan)
    diff = (raw1 - raw0)[np.abs(raw1 - raw0) > 1e-9]
    assert len(diff) == size["events"]
    mag = np.abs(diff)
    p2 = 2.0 ** np.round(np.log2(mag))
    assert np.all(np.abs(mag - p2) <= 0.5) and p2.min() >= 1024 and p2.max() <= 16384
    where = np.abs(raw1 - raw0).max(axis=1) > 0
    assert where.sum(axis=0).max() <= 2  # not a fixed defect


# ---- drift, noise floor --------------------------------------------------------------------


def test_random_walk_is_global_starts_at_zero_and_wanders():
    ctx = _ctx(12, "desk", (20, 30, 24))
    plan, b, _, size = _build(l2.td_phase_random_walk, ctx, 0)
    _, d0, _ = _nl(ctx, lg.Plan())
    _, d1, _ = _nl(ctx, plan)
    per_t = (d1 - d0).reshape(ctx.t, -1)
    assert np.ptp(per_t, axis=1).max() < 1e-9 and abs(per_t[0, 0]) < 1e-12
    np.testing.assert_allclose(per_t[:, 0], size["walk_m"], atol=1e-9)
    assert abs(np.sqrt(np.mean(per_t[:, 0] ** 2)) - b) < 1e-6
    steps = np.diff(per_t[:, 0])
    assert (steps > 0).any() and (steps < 0).any()  # not a monotone warm-up


def test_hotspot_drift_rises_then_returns_with_a_fixed_spatial_profile():
    ctx = _ctx(12, "desk", (20, 30, 24))
    plan, b, _, size = _build(l2.td_hotspot_overshoot, ctx, 0)
    _, d0, _ = _nl(ctx, lg.Plan())
    _, d1, _ = _nl(ctx, plan)
    diff = (d1 - d0) * np.sign(size["b_m"])
    assert np.allclose(diff[0], 0)
    peak = diff.reshape(ctx.t, -1).max(axis=1)
    tp = int(np.argmax(peak))
    assert 0 < tp < ctx.t - 1 and peak[-1] < 0.9 * peak[tp]
    prof = diff[tp] / diff[tp].max()
    np.testing.assert_allclose(diff[-1] / diff[-1].max(), prof, atol=1e-6)
    assert prof.min() < 0.8


@pytest.mark.parametrize("builder", [l2.nf_source_intensity_noise, l2.nf_row_clock_jitter])
def test_noise_floor_does_not_fall_with_amplitude(builder):
    ctx = _ctx(13, "aisle", (40, 60, 24))
    _, d0, _ = _nl(ctx, lg.Plan())
    plan = _plan(builder, ctx)
    assert plan.temporal
    _, d1, _ = _nl(ctx, plan)
    sd = np.std(d1 - d0, axis=0)
    a = ctx.amp0_dn
    lo, hi = a < np.quantile(a, 0.25), a > np.quantile(a, 0.75)
    assert sd.mean() > 0.005
    assert 0.6 < sd[hi].mean() / sd[lo].mean() < 1.6
    if builder is l2.nf_row_clock_jitter:  # the same along each row in each frame
        dd = d1 - d0
        assert np.ptp(dd, axis=2).max() < 1e-9 and np.std(dd[:, :, 0], axis=1).min() > 1e-4


# ---- flying pixels, multipath ---------------------------------------------------------


@pytest.mark.parametrize("builder", [l2.fp_defocus_disc, l2.fp_pixel_crosstalk])
def test_flying_pixels_sit_on_depth_edges(builder):
    ctx = _ctx(14, "doorway", (48, 64, 2))
    _, d1, _ = _nl(ctx, _plan(builder, ctx))
    r = ctx.geom["r"]
    err = np.abs(d1 - r).max(axis=0)
    gy, gx = np.gradient(r)
    edge = np.hypot(gx, gy) > 0.2
    near_edge = ndimage.binary_dilation(edge, iterations=1)
    far = ~ndimage.binary_dilation(edge, iterations=5)
    assert far.mean() > 0.2
    assert err[near_edge].max() > 0.2
    assert np.median(err[near_edge]) > 5 * np.median(err[far])
    assert np.quantile(err[far], 0.9) < 0.03


def test_crosstalk_kernel_keeps_the_charge_and_favours_the_rows():
    k = l2.crosstalk_kernel(0.08, 0.04)
    assert abs(k.sum() - 1) < 1e-12 and k[1, 0] == 0.08 and k[0, 1] == 0.04


def test_subsurface_scattering_delays_the_objects_only():
    ctx = _ctx(15, "desk")
    plan, _, _, size = _build(l2.mp_subsurface_objects, ctx)
    _, d1, a1 = _nl(ctx, plan)
    _, _, a0 = _nl(ctx, lg.Plan())
    err = d1[0] - ctx.geom["r"]
    obj = l2._object_mask(ctx)
    assert 0 < obj.mean() < 0.5
    assert np.all(np.abs(err[~obj]) < 1e-9)
    assert (
        err[obj].min() > 0
        and abs(np.median(err[obj]) - size["delay_m_approx"]) < 0.5 * (size["delay_m_approx"])
    )
    assert np.all(a1[0][obj] < a0[0][obj])


def test_translucent_sheet_pulls_the_covered_pixels_towards_the_sheet():
    ctx = _ctx(15, "aisle")
    plan, _, _, size = _build(l2.mp_translucent_sheet, ctx)
    _, d1, _ = _nl(ctx, plan)
    err = d1[0] - ctx.geom["r"]
    cov = np.abs(err) > 1e-9
    assert 0.2 < cov.mean() < 0.7
    # where the two returns are less than half the range apart, the covered pixels lie between
    # the sheet and the scene (nearer than the truth); farther apart, the sum's phase may wrap
    d = lg._rays(ctx.h, ctx.w, ctx.spec.pitch_deg)
    rs = size["sheet_m"] / d[..., 2]
    close = cov & (ctx.geom["r"] - rs < 0.45 * lg.RANGE_M)
    assert close.mean() > 0.1
    assert np.all(err[close] < 0) and np.all(d1[0][close] > rs[close] - 1e-6)
    # a covered column block: the sheet has a vertical edge, whole columns are covered or not
    col = cov.mean(axis=0)
    assert np.mean((col > 0.9) | (col < 0.1)) > 0.9


# ---- the benchmark script --------------------------------------------------------------------


def test_case_list_of_the_second_heldout_part():
    cases = bl.case_list("heldout2", 1, 4)
    n_forms = sum(len(v) for v in l2.HELDOUT2_FORMS.values())
    assert len(cases) == n_forms + 4 and min(c[2] for c in cases) == l2.SEED0
    assert [c[0] for c in cases[-4:]] == ["none"] * 4
    with pytest.raises(ValueError):
        bl.case_list("heldout3", 1, 1)
