"""The flexible multipath member's fit: its non-negative least squares against SciPy's, and the
refinement of the relaying blocks to single source patches."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import nnls as scipy_nnls

from tof_fpn_torch.diagnosis.model import predict
from tof_fpn_torch.diagnosis.terms.multipath_sources import (
    SOURCE_BLOCK,
    _grid,
    nnls,
    update_sources,
)


@pytest.mark.parametrize("seed", range(6))
def test_nnls_matches_scipy(seed):
    """``nnls(A'A, A'y)`` is ``scipy.optimize.nnls(A, y)``: the same minimum and, for a full
    column rank ``A``, the same solution (tall and wide systems, active bounds)."""
    rng = np.random.default_rng(seed)
    m, n = [(40, 12), (30, 30), (12, 25), (60, 5), (50, 40), (9, 6)][seed]
    a = rng.standard_normal((m, n))
    y = rng.standard_normal(m) + a @ np.where(rng.random(n) < 0.5, rng.random(n), 0.0)
    x = nnls(a.T @ a, a.T @ y)
    ref, _ = scipy_nnls(a, y)
    assert (x >= 0).all()
    cost = lambda v: float(np.sum((a @ v - y) ** 2))  # noqa: E731
    assert cost(x) == pytest.approx(cost(ref), rel=1e-9, abs=1e-9)
    if m >= n:
        np.testing.assert_allclose(x, ref, atol=1e-7)
    assert 0 < int((x > 0).sum()) < n  # some bounds active, some not: both paths exercised


def test_sources_of_one_relaying_patch_are_found_one_by_one():
    """A relay from a single source patch (the simulator's ``Multipath`` with a source map that
    is zero but for that patch): the member's fit puts the largest weight on that patch, and
    almost all of the relaying weight within its block (the first step, one weight per block,
    would spread it over the block's ``SOURCE_BLOCK``^2 patches equally), and the geometry
    without the cosines (the relay's own)."""
    from test_diagnosis import H, W, _recording

    from tof_fpn_torch.diagnosis.fit import fit
    from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe
    from tof_fpn_torch.sim import Multipath

    step, ny, nx = _grid(H, W)
    sy, sx = 1, 4  # the relaying patch (source row, column)
    smap = torch.zeros(H, W, dtype=torch.float64)
    smap[sy * step : (sy + 1) * step, sx * step : (sx + 1) * step] = 1.0
    term = Multipath(scene_relay=3.0, source_map=smap, near_field=0.2, cosines=False)  # ~4 %
    rec, scene = _recording(term, seed=3, frames=6)
    obs = observe(rec, scene)
    base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
    model, _ = fit(base.with_effect("multipath_sources", {}), obs, ctx)
    wts = model.profiles["multipath_sources"]
    assert tuple(wts.shape) == (ny, nx)
    assert tuple(int(i) for i in np.unravel_index(int(wts.argmax()), wts.shape)) == (sy, sx)
    by, bx = sy // SOURCE_BLOCK, sx // SOURCE_BLOCK
    block = wts[
        by * SOURCE_BLOCK : (by + 1) * SOURCE_BLOCK, bx * SOURCE_BLOCK : (bx + 1) * SOURCE_BLOCK
    ]
    assert float(wts[sy, sx]) > 0.6 * float(block.sum())
    assert float(wts[sy, sx]) > 0.6 * float(wts.sum())
    assert model.values["multipath_sources.cosines"] == 0.0
    # in a candidate's fit (the fitting half) its groups are kept and only their weights
    # refitted: with every source in one group, one weight; a fit of all the pixels chooses
    # them again
    one = model.copy()
    one.profiles["multipath_sources_groups"] = torch.zeros(ny, nx, dtype=torch.float64)
    with torch.no_grad():
        pred = predict(one, obs, scene=ctx.scene)
    again = update_sources(one, obs, ctx, pred, "train")
    w1 = again.profiles["multipath_sources"]
    assert float(w1.max()) > 0 and torch.equal(w1, torch.full_like(w1, float(w1[0, 0])))
    assert again.values["multipath_sources.dof"] == 3.0  # one weight and the geometry
    chosen = update_sources(one, obs, ctx, pred, "all").profiles["multipath_sources"]
    assert int(chosen.argmax()) == sy * nx + sx and float(chosen.max()) > 0.6 * float(chosen.sum())


def test_a_hint_that_no_longer_preconditions_is_replaced():
    """A candidate's fit whitens with the core Hessian of a nearby model (the ``hint``); where
    that whitening lets L-BFGS make no step (a closed-form update moved the model far from it:
    the member's relay of a strong patch, whose ranking then saw a sixth of its gain) it is
    replaced by a fresh one: a hint that freezes every step (a Hessian 1e30 too large) gives the
    fit without a hint, step for step, where it used to leave the start as it was."""
    from test_diagnosis import _recording

    from tof_fpn_torch.diagnosis.fit import evaluate, fit
    from tof_fpn_torch.diagnosis.model import CORE_SPECS
    from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe

    rec, scene = _recording(None, seed=5, frames=6)
    obs = observe(rec, scene)
    base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
    core = [s.key for s in CORE_SPECS]
    start = base.copy()
    start.values["photons.responsivity"] *= 1.5  # far from the optimum
    frozen = {"keys": core, "matrix": 1e30 * torch.eye(len(core), dtype=torch.float64)}
    _, hinted = fit(start, obs, ctx, "train", free=core, iters=20, hint=frozen)
    _, fresh = fit(start, obs, ctx, "train", free=core, iters=20)
    assert hinted == pytest.approx(fresh, rel=1e-9)
    assert hinted < evaluate(start, obs, ctx, "train") - 100.0
