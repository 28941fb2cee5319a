"""The literature generator (benchmarks/literature_generator.py, literature_heldout.py) and the
scoring of benchmarks/bench_literature.py, without any diagnosis: shapes, validity, every planted
effect changing the raw samples the way its form says, effect-free nulls, determinism."""

from __future__ import annotations

import bench_literature as bl
import literature_generator as lg
import literature_heldout as lh
import numpy as np
import pytest

SIZE = (36, 48, 6)


def _ctx(seed=0, scene="room", size=SIZE):
    rng = np.random.default_rng(seed)
    spec = (lg.DEV_SCENES | lh.HELDOUT_SCENES)[scene](rng)
    return lg.make_ctx(spec, *size, rng)


def _nl(ctx, plan):
    """Noiseless render: raw, depth, amplitude."""
    return lg.render(ctx, plan, None)


def _plan(builder, ctx, seed=1):
    return builder(ctx, np.random.default_rng(seed))[0]


ALL = [("dev", f, fo) for f in lg.DEV_FORMS for fo in lg.DEV_FORMS[f]] + [
    ("heldout", f, fo) for f in lh.HELDOUT_FORMS for fo in lh.HELDOUT_FORMS[f]
]


def check_recording(r: dict, size: tuple, min_depth: float) -> None:
    """The recording dict's format: shapes, dtypes, meta, the scene's ranges, raw samples in
    16-bit counts, NaN exactly where the amplitude is below the camera's threshold."""
    h, w, t = size
    assert r["depth"].shape == (t, h, w) and r["depth"].dtype == np.float32
    assert r["amplitude"].shape == (t, h, w) and r["amplitude"].dtype == np.float32
    assert r["raw"].shape == (t, 4, h, w) and r["raw"].dtype == np.float32
    assert r["scene_depth"].shape == (h, w) and r["scene_depth"].dtype == np.float64
    assert r["reflectance"].shape == (h, w)
    assert r["meta"]["n_phases"] == 4 and r["meta"]["amplitude_unit"] == "DN"
    assert r["meta"]["modulation_frequency_hz"] == lg.F_MOD
    assert r["meta"]["source"] == "benchmarks/literature_generator.py"
    assert r["meta"]["integration_time_us"] > 0
    assert min_depth <= r["scene_depth"].min() and r["scene_depth"].max() <= 6.0
    assert 0.05 <= r["reflectance"].min() and r["reflectance"].max() <= 0.95
    raw = r["raw"]
    assert raw.min() >= 0 and raw.max() <= 65535 and np.all(raw == np.round(raw))
    # NaN exactly where the amplitude is below the camera's threshold (depth 0 is invalid too)
    invalid = (r["amplitude"] < lg.AMP_MIN_DN) | (r["depth"] == 0)
    assert np.array_equal(np.isnan(r["depth"]), invalid)
    d = r["depth"][~invalid]
    assert d.min() > 0 and d.max() < lg.RANGE_M


@pytest.mark.parametrize("part,family,form", ALL + [("dev", "none", "null")])
def test_shapes_dtypes_meta_and_nan_only_where_invalid(part, family, form):
    gen = lg.generate if part == "dev" else lh.generate
    r = gen(family, form, 3, SIZE)
    check_recording(r, SIZE, 0.4)
    tr = r["truth"]
    assert (tr["family"], tr["form"], tr["part"]) == (family, form, part)
    if family != "none":
        assert tr["citation"] and tr["stats"]["affected_fraction"] > 0


def test_decode_recovers_a_known_phase_and_amplitude():
    phi, a, b = 2.0, 300.0, 1000.0
    raw = b + a * np.cos(phi - lg.THETA)
    d, amp = lg.decode(raw.reshape(1, 4, 1, 1))
    assert abs(d[0, 0, 0] - phi * lg.M_PER_RAD) < 1e-9 and abs(amp[0, 0, 0] - a) < 1e-9


def test_null_is_effect_free():
    r = lg.generate("none", "null", 11, (60, 80, 24))
    assert "stats" not in r["truth"] and r["truth"]["magnitude"] == 0.0
    assert r["meta"]["integration_time_us"] == lg.BASE_INTEGRATION_US
    assert r["raw"].max() < lg.ADC_MAX and (r["raw"] - lg.BLACK_DN).max() < lg.CONV_GAIN * (
        lg.FULL_WELL
    )
    # the temporal mean sits on the true depth within the shot/read noise: no bias, no pattern
    err = np.nanmean(r["depth"], axis=0) - r["scene_depth"]
    sd = np.nanstd(r["depth"], axis=0) / np.sqrt(24)
    z = err / sd
    assert abs(np.nanmedian(z)) < 0.2 and np.nanmean(np.abs(z) > 4) < 0.01
    # the noiseless null renders the scene exactly
    ctx = _ctx(11, "corridor", (60, 80, 4))
    _, d, _ = _nl(ctx, lg.Plan())
    assert np.abs(d - ctx.geom["r"]).max() < 1e-9


@pytest.mark.parametrize("part,family,form", ALL[:6] + [("dev", "none", "null")])
def test_deterministic_per_seed(part, family, form):
    gen = lg.generate if part == "dev" else lh.generate
    a = gen(family, form, 5, SIZE)
    b = gen(family, form, 5, SIZE)
    c = gen(family, form, 6, SIZE)
    for k in ("depth", "amplitude", "raw", "scene_depth"):
        np.testing.assert_array_equal(a[k], b[k])
    assert not np.array_equal(a["raw"], c["raw"])
    assert a["truth"] == b["truth"]


def test_dev_and_heldout_forms_differ_and_cover_every_family():
    assert set(lg.DEV_FORMS) == set(lh.HELDOUT_FORMS)
    for fam in lg.DEV_FORMS:
        assert not set(lg.DEV_FORMS[fam]) & set(lh.HELDOUT_FORMS[fam]), fam
        assert set(lg.DEV_FORMS[fam].values()).isdisjoint(lh.HELDOUT_FORMS[fam].values())
        need = 3 if fam in ("saturation", "fpn_pattern", "amplitude_bias") else 2
        assert len(lg.DEV_FORMS[fam]) >= need, fam
        assert len(lh.HELDOUT_FORMS[fam]) >= 1
    assert not set(lg.DEV_SCENES) & set(lh.HELDOUT_SCENES)
    assert lg.cases(lg.DEV_FORMS, 1, 0, 0)[-1][2] < lh.SEED0


# ---- saturation ------------------------------------------------------------------------------


def test_adc_clip_no_sample_above_full_scale_and_the_planned_share_clipped():
    ctx = _ctx(2, "room")
    plan, p, _, _ = lg.sat_adc_clip(ctx, np.random.default_rng(0))
    raw, _, _ = _nl(ctx, plan)
    assert raw.max() <= lg.ADC_MAX
    share = np.mean(raw >= lg.ADC_MAX)
    assert abs(share - p) < 0.01, (share, p)
    # the ADC clips before the well: no sample's electrons reach the well
    assert ((raw - lg.BLACK_DN) / plan.conv_gain).max() < lg.FULL_WELL


def test_well_prnu_clips_each_pixel_at_its_own_well():
    ctx = _ctx(2, "room")
    plan, p, _, _ = lg.sat_well_prnu(ctx, np.random.default_rng(0))
    raw, _, _ = _nl(ctx, plan)
    e = (raw - lg.BLACK_DN) / lg.CONV_GAIN
    fw = plan.full_well
    assert np.all(e <= fw[None, None] + 1e-6)
    at = np.isclose(e, fw[None, None])
    assert abs(at.mean() - p) < 0.01
    assert np.ptp(e[at]) > 0.02 * lg.FULL_WELL  # the clip level varies from pixel to pixel
    assert raw.max() < lg.ADC_MAX


def test_log_knee_is_linear_below_and_compressive_above():
    ctx = _ctx(2, "room")
    plan, _, _, size = lg.sat_log_knee(ctx, np.random.default_rng(0))
    e = np.linspace(0, 3 * lg.FULL_WELL, 2001)
    out = plan.response(e)
    k = size["knee_e"]
    np.testing.assert_allclose(out[e <= k], e[e <= k])
    slope = np.diff(out) / np.diff(e)
    assert np.all(slope > 0) and np.all(slope[e[1:] > k * 1.01] < 1)
    assert np.all(np.diff(slope[e[1:] > k * 1.01]) <= 1e-12)


def test_heldout_sunlit_patch_and_blooming():
    ctx = _ctx(4, "lobby")
    plan = _plan(lh.sat_sunlit_patch, ctx)
    raw, d, amp = _nl(ctx, plan)
    full = (raw - lg.BLACK_DN) / lg.CONV_GAIN >= lg.FULL_WELL - 1e-6
    allfull = full.all(axis=1)
    assert allfull.any() and np.all(np.isnan(d[allfull]))  # all four clipped: no phase left
    plan = _plan(lh.sat_vertical_blooming, ctx)
    e = np.full((1, 4, 5, 1), 0.5 * lg.FULL_WELL)
    e[0, :, 2, 0] = 3.0 * lg.FULL_WELL  # 2 wells of excess: one to each vertical neighbour
    out = plan.response(e)
    assert np.allclose(out[0, :, 2, 0], lg.FULL_WELL)
    assert np.allclose(out[0, :, [1, 3], 0], 1.5 * lg.FULL_WELL)
    assert np.allclose(out[0, :, [0, 4], 0], 0.5 * lg.FULL_WELL)


# ---- fixed pattern -----------------------------------------------------------------------


@pytest.mark.parametrize(
    "builder",
    [
        lg.fpn_column_adc_offsets,
        lg.fpn_row_offsets,
        lg.fpn_dsnu_tap_map,
        lh.fpn_split_readout_halves,
        lh.fpn_tap_gain_mismatch,
    ],
)
def test_raw_fpn_is_the_same_offset_in_every_frame(builder):
    ctx = _ctx(5, "wall_target")
    raw0, _, _ = _nl(ctx, lg.Plan())
    raw1, d1, _ = _nl(ctx, _plan(builder, ctx))
    diff = raw1 - raw0
    assert np.abs(diff).max() > 1.0
    np.testing.assert_allclose(diff, np.broadcast_to(diff[:1], diff.shape), atol=1e-9)
    if builder is lg.fpn_column_adc_offsets:  # constant down each column, per sample
        np.testing.assert_allclose(diff, np.broadcast_to(diff[:, :, :1], diff.shape), atol=1e-9)
        assert np.std(diff[0], axis=2).min() > 0.5
    if builder is lg.fpn_row_offsets:  # constant along each row
        np.testing.assert_allclose(diff, np.broadcast_to(diff[:, :, :, :1], diff.shape), atol=1e-9)
        # a complex offset: the four samples' offsets sum to zero (the DC is untouched)
        np.testing.assert_allclose(diff.sum(axis=1), 0, atol=1e-9)
    if builder is lh.fpn_split_readout_halves:
        h = ctx.h // 2
        top, bot = diff[0, :, :h], diff[0, :, h:]
        assert np.allclose(top, top[:, :1]) and np.allclose(bot, bot[:, :1])
        assert not np.allclose(top[:, 0], bot[:, 0])


@pytest.mark.parametrize("builder", [lg.fpn_column_1f_phase, lg.fpn_kinect_p0])
def test_phase_fpn_is_a_fixed_depth_offset(builder):
    ctx = _ctx(5, "room")
    plan, _, _, size = builder(ctx, np.random.default_rng(1))
    _, d0, _ = _nl(ctx, lg.Plan())
    _, d1, a1 = _nl(ctx, plan)
    diff = d1 - d0
    np.testing.assert_allclose(diff, np.broadcast_to(diff[:1], diff.shape), atol=1e-9)
    np.testing.assert_allclose(diff[0], plan.phase * lg.M_PER_RAD, atol=1e-9)
    assert abs(np.std(diff[0]) - size["depth_rms_m"]) < 0.2 * size["depth_rms_m"]


def test_kinect_p0_map_comes_from_the_file():
    """The fine structure of the real P0 tables: zero mean, 3-20 mrad rms, and a different crop of
    another table differs; the data file must be there."""
    rng = np.random.default_rng(0)
    for k in range(3):
        m = lg.p0_fine_structure(100, 120, rng, table=k)
        assert abs(m.mean()) < 2e-3 and 0.003 < m.std() < 0.02
    a = np.fromfile(lg.P0_FILE, dtype="<u2").reshape(3, 424, 512)
    assert a.shape == (3, 424, 512) and a.max() > 30000
    m0 = lg.p0_fine_structure(424 - 4, 512 - 8, np.random.default_rng(0), table=0)
    raw = np.mod(a[0].astype(float), 32768.0)[2:-2, 4:-4]
    # the map follows the table pixel by pixel
    assert np.corrcoef(m0.ravel(), raw.ravel() - raw.mean())[0, 1] > 0.1


# ---- amplitude bias ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "builder",
    [lg.ab_lindner_kolb_log, lg.ab_weakest_pixels, lg.ab_exp_decay, lh.ab_tanh_crossing],
)
def test_amplitude_bias_is_monotone_in_amplitude(builder):
    ctx = _ctx(7, "room")
    _, d0, _ = _nl(ctx, lg.Plan())
    _, d1, _ = _nl(ctx, _plan(builder, ctx))
    bias = (d1 - d0)[0].ravel()
    order = np.argsort(ctx.amp0_dn.ravel())
    b = bias[order]
    step = np.diff(b)
    assert np.abs(b).max() > 0.01
    assert np.all(step <= 1e-9) or np.all(step >= -1e-9)  # monotone, either sign
    if builder is lg.ab_weakest_pixels:
        share = np.mean(np.abs(bias) > 1e-9)
        assert 0.01 < share < 0.07
        assert np.all(bias[order][int(0.1 * len(b)) :] == 0)
    if builder is lh.ab_tanh_crossing:
        assert b.min() < -0.005 and b.max() > 0.005  # it changes sign


# ---- cyclic error ------------------------------------------------------------------------


def _fit_share(err, basis):
    x = np.stack(basis + [np.ones_like(err)], 1)
    coef, *_ = np.linalg.lstsq(x, err, rcond=None)
    return 1 - np.var(err - x @ coef) / np.var(err)


@pytest.mark.parametrize(
    "builder,k", [(lg.ce_square_wave, 4), (lg.ce_triangular, 4), (lh.ce_phase_step_error, 2)]
)
def test_cyclic_error_has_its_period_in_phase(builder, k):
    """Odd harmonics seen through 4 samples: an error in multiples of 4 phi (3rd, 5th -> 4 phi, 7th
    -> 8 phi); phase-step errors: 2 phi."""
    ctx = _ctx(8, "corridor")
    _, d, _ = _nl(ctx, _plan(builder, ctx))
    err = (d[0] - ctx.geom["r"]).ravel()
    phi = ctx.phi.ravel()
    assert np.abs(err).max() > 0.01

    def basis(m):
        return [np.sin(m * phi), np.cos(m * phi), np.sin(2 * m * phi), np.cos(2 * m * phi)]

    assert _fit_share(err, basis(k)) > 0.95
    other = 2 if k == 4 else 4
    assert _fit_share(err, [np.sin(other * phi), np.cos(other * phi)]) < 0.3


# ---- gains, vignetting ------------------------------------------------------------------


@pytest.mark.parametrize(
    "builder",
    [
        lg.pg_prnu_white,
        lg.pg_column_gain,
        lg.vig_cos4,
        lg.vig_led_lambertian,
        lh.pg_dust_shadows,
        lh.vig_led_ring_offaxis,
    ],
)
def test_gains_scale_the_amplitude_and_leave_the_depth(builder):
    ctx = _ctx(9, "room")
    plan = _plan(builder, ctx)
    _, d0, a0 = _nl(ctx, lg.Plan())
    _, d1, a1 = _nl(ctx, plan)
    np.testing.assert_allclose(d1, d0, atol=1e-9)
    g = np.asarray(plan.gain_light) * np.asarray(plan.gain_active)
    np.testing.assert_allclose(a1, a0 * g, rtol=1e-6)  # amplitude kept in float32
    assert np.std(g) > 0.01
    if builder in (lg.vig_cos4, lg.vig_led_lambertian):  # falls with the field angle
        ang = lg.field_angle(ctx).ravel()
        gg = np.broadcast_to(g, ang.reshape(ctx.h, ctx.w).shape).ravel()[np.argsort(ang)]
        assert np.all(np.diff(gg) <= 1e-12) and gg[0] > 0.99


# ---- impulsive ---------------------------------------------------------------------------


def test_hot_pixels_and_rts_touch_few_pixels():
    ctx = _ctx(10, "room")
    plan, f, _, _ = lg.imp_hot_pixels(ctx, np.random.default_rng(0))
    hot = (np.asarray(plan.dark_extra) > 0).any(0)
    assert abs(hot.mean() - f) < 0.002
    raw0, _, _ = _nl(ctx, lg.Plan())
    raw1, _, _ = _nl(ctx, plan)
    changed = (np.abs(raw1 - raw0) > 1e-9).any(axis=(0, 1))
    assert np.array_equal(changed, hot)
    assert np.allclose(raw1 - raw0, (raw1 - raw0)[:1])  # fixed in time
    plan, f, _, _ = lg.imp_dark_rts(ctx, np.random.default_rng(0))
    dk = np.asarray(plan.dark_extra)
    pix = (dk > 0).any(axis=(0, 1))
    assert abs(pix.mean() - f) < 0.003
    switching = 0
    for y, x in zip(*np.nonzero(pix), strict=True):
        levels = np.unique(dk[:, :, y, x].max(axis=1))
        assert len(levels) <= 2 and np.count_nonzero(dk[:, :, y, x].max(axis=0)) == 1
        switching += len(levels) == 2 and levels[0] == 0  # two states, switching in time
    assert switching > 0.7 * pix.sum()


def test_transient_hits_never_repeat():
    ctx = _ctx(10, "lobby")
    dk = np.asarray(_plan(lh.imp_transient_hits, ctx).dark_extra)
    hit = (dk > 0).any(axis=1)
    assert hit.any() and hit.sum(axis=0).max() <= 3


# ---- drift, noise floor --------------------------------------------------------------


def test_warmup_drift_is_global_and_monotone_in_time():
    ctx = _ctx(12, "room")
    plan, _, _, size = lg.td_warmup_exp(ctx, np.random.default_rng(0))
    _, d0, _ = _nl(ctx, lg.Plan())
    _, d1, _ = _nl(ctx, plan)
    diff = d1 - d0
    per_t = diff.reshape(ctx.t, -1)
    assert np.ptp(per_t, axis=1).max() < 1e-9  # the same in every pixel
    s = np.sign(size["drift_m"])
    assert np.all(np.diff(s * per_t[:, 0]) > 0) and per_t[0, 0] == 0


def test_thermal_gradient_grows_in_time_and_across_columns():
    ctx = _ctx(12, "room")
    _, d0, _ = _nl(ctx, lg.Plan())
    _, d1, _ = _nl(ctx, _plan(lg.td_thermal_gradient, ctx))
    diff = d1 - d0
    assert np.allclose(diff[0], 0)
    col = diff[-1, 0]
    assert np.all(np.diff(col) > 0) or np.all(np.diff(col) < 0)


@pytest.mark.parametrize(
    "builder", [lg.nf_gaussian_phase_jitter, lg.nf_tap_timing_jitter, lh.nf_dual_dirac_jitter]
)
def test_noise_floor_does_not_fall_with_amplitude(builder):
    ctx = _ctx(13, "objects_field", (40, 60, 24))
    _, d0, _ = _nl(ctx, lg.Plan())
    _, d1, _ = _nl(ctx, _plan(builder, ctx))
    sd = np.std(d1 - d0, axis=0)
    a = ctx.amp0_dn
    lo, hi = a < np.quantile(a, 0.25), a > np.quantile(a, 0.75)
    assert sd.mean() > 0.01
    assert 0.7 < sd[hi].mean() / sd[lo].mean() < 1.4


# ---- flying pixels, multipath ---------------------------------------------------------


@pytest.mark.parametrize(
    "builder", [lg.fp_pixel_footprint_mix, lg.fp_lens_psf_gaussian, lh.fp_tap_motion]
)
def test_flying_pixels_sit_on_depth_edges(builder):
    """The errors are on depth edges, not inside the surfaces."""
    from scipy import ndimage

    ctx = _ctx(14, "objects_field", (48, 64, 3))
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
    if builder is not lh.fp_tap_motion:  # a static footprint: ~1 cm at most on slanted floors
        assert np.quantile(err[far], 0.9) < 0.03


@pytest.mark.parametrize(
    "builder", [lg.mp_specular_floor, lg.mp_diffuse_interreflection, lh.mp_glossy_side_wall]
)
def test_multipath_makes_surfaces_farther(builder):
    scene = "lobby" if builder is lh.mp_glossy_side_wall else "room"
    ctx = _ctx(15, scene)
    _, d1, a1 = _nl(ctx, _plan(builder, ctx))
    err = d1[0] - ctx.geom["r"]
    assert err.max() > 0.02
    assert np.quantile(err, 0.01) > -1e-3  # the longer second path only adds delay


def test_bspline_error_depends_on_distance_only():
    ctx = _ctx(16, "stairs")
    _, d1, _ = _nl(ctx, _plan(lh.ce_distance_bspline, ctx))
    err = d1[0] - ctx.geom["r"]
    r = ctx.geom["r"]
    i = np.argsort(r.ravel())
    e = err.ravel()[i]
    close = np.diff(r.ravel()[i]) < 1e-4
    assert np.abs(e).max() > 0.01 and np.abs(np.diff(e)[close]).max() < 1e-3


# ---- the benchmark's scoring ---------------------------------------------------------------


def test_score_counts_first_names_false_alarms_and_beyond():
    rows = [
        {"family": "saturation", "form": "a", "seed": 0, "names": ["saturation"]},
        {"family": "saturation", "form": "b", "seed": 1, "names": ["vignetting", "saturation"]},
        {"family": "saturation", "form": "b", "seed": 2, "names": []},
        {"family": "multipath", "form": "c", "seed": 3, "names": ["multipath", "fpn_pattern"]},
        {"family": "none", "form": "null", "seed": 4, "names": []},
        {"family": "none", "form": "null", "seed": 5, "names": ["noise_floor"]},
    ]
    sc = bl.score(rows)
    sat = sc["per_family"]["saturation"]
    assert (sat["n"], sat["top1"], sat["beyond"]) == (3, 1, 1)
    assert sc["per_form"]["saturation/b"]["top1"] == 0
    assert sc["per_family"]["multipath"]["beyond_share"] == 1.0
    assert sc["nulls"] == {"n": 2, "false_alarms": 1, "false_alarm_share": 0.5}
    assert sc["totals"]["top1"] == 2 and sc["totals"]["recordings"] == 4
    named = {(m["family"], m["seed"]): m["named"] for m in sc["misses"]}
    assert named == {
        ("saturation", 1): ["vignetting", "saturation"],
        ("saturation", 2): [],
        ("none", 5): ["noise_floor"],
    }


def test_case_list_counts_forms_and_nulls():
    cases = bl.case_list("dev", 2, 3)
    n_forms = sum(len(v) for v in lg.DEV_FORMS.values())
    assert len(cases) == 2 * n_forms + 3
    assert [c[0] for c in cases[-3:]] == ["none"] * 3
    assert len({c[2] for c in cases}) == len(cases)
    held = bl.case_list("heldout", 1, 1)
    assert min(c[2] for c in held) == lh.SEED0


def test_recordings_are_accepted_by_the_package_as_recording_and_scene():
    r = lh.generate("saturation", "sunlit_patch", lh.SEED0, SIZE)
    rec, scene = bl.to_inputs(r)
    h, w, t = SIZE
    assert tuple(rec.depth.shape) == (t, 1, h, w) and tuple(rec.raw.shape) == (t, 4, h, w)
    # the recording keeps the generator's invalid pixels as NaN and no others
    assert np.array_equal(np.isnan(rec.depth.numpy()[:, 0]), np.isnan(r["depth"]))
    assert rec.meta["n_phases"] == 4 and rec.meta["amplitude_unit"] == "DN"
    np.testing.assert_array_equal(scene.depth.numpy()[0, 0], r["scene_depth"].astype(np.float32))
