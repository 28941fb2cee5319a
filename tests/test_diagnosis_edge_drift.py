"""The edge mixture (``mixed_pixels``) together with a per-frame term (``temporal_drift``): the
mixture replaces the cost the frame-level NLL counted for an edge pixel, so its no-mixing cost
must be that same cost, computed on the frames with the per-frame means taken out."""

from __future__ import annotations

import torch
from test_diagnosis_terms import setup  # noqa: F401  (the fixture: a small recording's model)

from tof_fpn_torch.diagnosis.catalogue import CATALOGUE
from tof_fpn_torch.diagnosis.fit import evaluate
from tof_fpn_torch.diagnosis.likelihood import _frame_adjusted, _nll_frames, _nll_pooled
from tof_fpn_torch.diagnosis.prediction import predict

DRIFT = {
    "temporal_drift.depth_step": 0.011,
    "temporal_drift.amplitude_step": -0.88,
    "temporal_drift.time_constant": 1e-3,
}
DRIFT_TERM = CATALOGUE["temporal_drift"]


def test_frame_adjusted_statistics_give_the_frames_cost(setup):  # noqa: F811
    """The pooled NLL of the adjusted statistics is the frame-level NLL with the drift."""
    obs, model, ctx, _ = setup
    m = model.with_effect(DRIFT_TERM, DRIFT)
    with torch.no_grad():
        pred = predict(m, obs, scene=ctx.scene)
        per_frame = [DRIFT_TERM.frame_means(m.values, obs, m)]
        for sel in ("all", "train", "test"):
            frames = float(_nll_frames(obs, ctx, pred, sel, per_frame, None))
            o2, p2 = _frame_adjusted(obs, pred, per_frame)
            pooled = float(_nll_pooled(o2, ctx, p2, sel))
            assert abs(frames - pooled) < 1e-6 * abs(frames), (sel, frames, pooled)
            # and the drift matters: without it the pooled cost is another
            assert abs(float(_nll_pooled(obs, ctx, pred, sel)) - frames) > 100.0


def test_a_drift_does_not_take_the_edge_mixture_below_any_bound(setup):  # noqa: F811
    """A drift that leaves frame 0's prediction far from the frames' mean, with mixed edge
    pixels: the NLL per observation stays that of a density (it fell to -1e14 when the mixture
    subtracted the pooled, drift-free cost of its edge pixels)."""
    obs, model, ctx, _ = setup
    m = model.with_effect(DRIFT_TERM, DRIFT).with_effect(
        CATALOGUE["mixed_pixels"], {"mixed_pixels.probability": 0.5}
    )
    without = model.with_effect(DRIFT_TERM, DRIFT)
    with torch.no_grad():
        both, drift_only = evaluate(m, obs, ctx), evaluate(without, obs, ctx)
    # mixing edge pixels with probability one half changes the NLL by at most the edge pixels'
    # share of it, either way; it cannot make a misfit of the drift vanish
    assert both > 0.5 * drift_only, (both, drift_only)
