"""The fitted parameters' kinds: every kind maps the optimiser's variable to its physical value
and back, keeps the value in its stated range wherever the optimiser goes, and every catalogue
term's simulator term accepts any value its parameters can take (a fit that wanders far must
not stop the bootstrap that simulates the fitted model)."""

from __future__ import annotations

import pytest
import torch
from test_diagnosis_terms import setup  # noqa: F401  (the fixture: a small recording's model)

from tof_fpn_torch.diagnosis.catalogue import CATALOGUE
from tof_fpn_torch.diagnosis.params import ParamSpec, from_u, to_u
from tof_fpn_torch.diagnosis.prediction import predict

KINDS = ("lin", "log", "logit", "relgain", "abs", "rootabs")


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("value", [0.003, 0.4, 2.5])
def test_kinds_round_trip(kind, value):
    spec = ParamSpec("x.y", kind, 3.0 if kind == "logit" else 0.5)  # logit: values in (0, 3)
    u = to_u(spec, value)
    assert from_u(spec, u) == pytest.approx(value, rel=1e-9)
    # the tensor path gives the same value (the fit moves tensors)
    assert float(from_u(spec, torch.tensor(u, dtype=torch.float64))) == pytest.approx(
        value, rel=1e-9
    )


def test_relgain_is_a_relative_change_that_never_reaches_minus_one():
    spec = ParamSpec("x.y", "relgain", 0.01)
    # near zero it moves like a linear parameter of that scale ...
    assert from_u(spec, 1.0) == pytest.approx(0.01, rel=1e-2)
    assert from_u(spec, -1.0) == pytest.approx(-0.01, rel=1e-2)
    # ... and however far the optimiser goes down, the level stays positive
    for u in (-300.0, -3000.0, -1e6):
        a = from_u(spec, u)
        assert -1.0 <= a < -0.95
        assert float(from_u(spec, torch.tensor(u, dtype=torch.float64))) >= -1.0
    assert to_u(spec, -1.5) < -1000  # a value out of range maps to the far end, not an error


@pytest.mark.parametrize(
    "name", [n for n, t in CATALOGUE.items() if t.specs and t.enters != "chain"]
)
def test_simulator_term_accepts_every_value_the_fit_can_reach(setup, name):  # noqa: F811
    """Each parameter in turn at a far end of its optimiser variable (the others at their
    start): the term's simulator term is built without error. (A term that enters the chain
    builds its simulator term in every step of the fit, where a refused value is an infeasible
    step; the others build it only for the bootstrap of the final model, so that a value the
    fit reached and the simulator refuses would stop the diagnosis.)"""
    obs, model, ctx, _ = setup
    term = CATALOGUE[name]
    with torch.no_grad():
        pred = predict(model, obs, scene=ctx.scene)
    m = model.with_effect(term, term.initial_values(model, obs, ctx, pred)[0])
    for s in term.specs:
        for u in (-1e4, -300.0, 300.0, 1e4):
            try:
                value = from_u(s, u)
            except OverflowError:
                continue
            moved = m.copy()
            moved.values[s.key] = value
            try:
                term.simulator_term(moved.values, moved)
            except ValueError as err:
                pytest.fail(f"{s.key} = {value!r} (u = {u}): {err}")


def test_whitening_survives_an_undefined_curvature():
    """A parameter whose gradient is infinite at the start (a square root at zero): the
    whitening is finite (it was NaN, and on a larger Hessian LAPACK's eigh raised and stopped a
    diagnosis) and that parameter moves by its own scale."""
    from tof_fpn_torch.diagnosis.fit import _whitening

    def objective(u):
        return u[0] ** 2 + torch.sqrt(u[1].abs()) + u[2] ** 2

    f0, tmat = _whitening(objective, torch.tensor([0.3, 0.0, 0.2], dtype=torch.float64))
    assert f0 == pytest.approx(0.13)
    assert bool(torch.isfinite(tmat).all())
    assert float(tmat[1].abs().max()) == pytest.approx(1.0)
    assert float(tmat[:, torch.argmax(tmat[1].abs())].abs().sum()) == pytest.approx(1.0)
