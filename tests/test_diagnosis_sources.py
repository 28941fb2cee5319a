"""The flexible multipath member's fit: its non-negative least squares against SciPy's, and the
refinement of the relaying blocks to single source patches."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.optimize import nnls as scipy_nnls

from tof_fpn_torch.diagnosis.nnls import nnls
from tof_fpn_torch.diagnosis.prediction import predict
from tof_fpn_torch.diagnosis.terms.multipath_sources import (
    SOURCE_BLOCK,
    _grid,
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

    from tof_fpn_torch.diagnosis.catalogue import CATALOGUE
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
    model, _ = fit(base.with_effect(CATALOGUE["multipath_sources"], {}), obs, ctx)
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
    mirrors = again.profiles.get("multipath_sources_mirrors")
    lit = 0 if mirrors is None else int((mirrors[:, 4] > 0).sum())
    assert again.values["multipath_sources.dof"] == 3.0 + lit  # one weight, geometry, mirrors
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


def test_a_mirror_floor_is_found_with_its_weight():
    """A specular second path off the floor of a box room (the simulator's ``Multipath`` with a
    mirror of weight 0.3): the member's fit finds the floor among the scene's planes and gives
    it about that weight, with little light left to the diffuse sources; the report describes
    the mirror."""
    from test_diagnosis import META, _sim
    from test_sim_optics import _room

    from tof_fpn_torch.diagnosis.catalogue import CATALOGUE
    from tof_fpn_torch.diagnosis.fit import fit
    from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe
    from tof_fpn_torch.io import Recording, SceneData
    from tof_fpn_torch.sim import Multipath, synthetic_scene, with_effect

    h, w = 40, 56
    depth = _room(h, w, 70.0).float()
    rho = synthetic_scene(h, w, seed=2).reflectance
    scene = type(synthetic_scene(h, w, seed=2))(depth=depth.view(1, 1, h, w), reflectance=rho)
    row = torch.tensor([[0.0, 1.0, 0.0, 1.2, 0.3]], dtype=torch.float64)
    term = Multipath(scene_relay=1.0, source_map=torch.zeros(h, w), mirrors=row)
    out = with_effect(_sim(), term).run(scene, 8, seed=4)
    dep = torch.where(out.depth > 0, out.depth, torch.full_like(out.depth, float("nan")))
    rec = Recording(dep, out.amplitude, dict(META, amplitude_unit="DN"))
    obs = observe(rec, SceneData(depth, rho[0, 0], meta={"source": "test"}))
    base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
    model, _ = fit(base.with_effect(CATALOGUE["multipath_sources"], {}), obs, ctx)
    mirrors = model.profiles["multipath_sources_mirrors"]
    floor = [m for m in mirrors if float(m[1]) > 0.99]
    assert len(floor) == 1 and float(floor[0][3]) == pytest.approx(1.2, abs=0.02)
    assert float(floor[0][4]) == pytest.approx(0.3, rel=0.15)
    others = [float(m[4]) for m in mirrors if float(m[1]) <= 0.99]
    assert max(others, default=0.0) < 0.05
    with torch.no_grad():
        pred = predict(model, obs, scene=ctx.scene)
    told = CATALOGUE["multipath_sources"].describe(model, obs, pred)
    assert told["mirrors"][0]["weight"] == pytest.approx(float(floor[0][4]), rel=1e-3)
