"""Which effect is named first (issue 10), and the benchmark generator's cyclic-error waveform.

``prune`` is backward elimination over the terms the forward rounds added: a term whose removal
costs less than ``naming.MIN_DAIC`` is dropped, and the rest are ordered by what their removal
costs. Tested with stand-in models whose NLL is a table over the set of terms (no fitting), so
the ordering rule itself is checked, including the case the forward rounds get wrong: a stand-in
term that wins the first round but adds little once the true term is in the model.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tof_fpn_torch.diagnosis import rounds as R
from tof_fpn_torch.diagnosis.naming import MIN_DAIC

ROOT = Path(__file__).resolve().parents[1]


class _Stub:
    """A model that is just its set of terms, each with one parameter."""

    def __init__(self, effects):
        self.effects = list(effects)

    def without(self, name):
        return _Stub([e for e in self.effects if e != name])

    def n_parameters(self):
        return float(len(self.effects))


def _patch(monkeypatch, table: dict):
    def nll(model):
        return table[frozenset(model.effects)]

    monkeypatch.setattr(R, "evaluate", lambda m, obs, ctx, sel="all": nll(m))
    monkeypatch.setattr(R, "fit", lambda m, obs, ctx, *a, **k: (m, nll(m)))


def _effects(*names):
    return [{"name": n, "score": 1.0, "delta_aic": -1.0} for n in names]


def test_the_term_no_other_explains_is_named_first(monkeypatch):
    # amplitude_bias was added first (it stands in for part of the cyclic error), but with
    # both in the model, dropping cyclic_error costs 600 nats and dropping amplitude_bias 40
    _patch(
        monkeypatch,
        {
            frozenset({"amplitude_bias"}): 1000.0,
            frozenset({"cyclic_error"}): 440.0,
            frozenset({"amplitude_bias", "cyclic_error"}): 400.0,
        },
    )
    model = _Stub(["amplitude_bias", "cyclic_error"])
    out, effects = R.prune(model, _effects("amplitude_bias", "cyclic_error"), None, None)
    assert [e["name"] for e in effects] == ["cyclic_error", "amplitude_bias"]
    # drop costs: 2 * (-1) + 2 * (nll without - nll with)
    assert effects[0]["drop_delta_aic"] == pytest.approx(-2 + 2 * (1000.0 - 400.0))
    assert effects[1]["drop_delta_aic"] == pytest.approx(-2 + 2 * (440.0 - 400.0))
    assert out.effects == ["amplitude_bias", "cyclic_error"]


def test_a_term_made_redundant_is_dropped_and_the_rest_ordered(monkeypatch):
    # three terms: fpn_pattern adds < MIN_DAIC once the other two are in; of the two left,
    # vignetting's removal costs more
    small = (MIN_DAIC - 4) / 2  # nats: a drop cost of 2 * small - 2 < MIN_DAIC
    full = 500.0
    _patch(
        monkeypatch,
        {
            frozenset({"fpn_pattern", "cyclic_error", "vignetting"}): full,
            frozenset({"cyclic_error", "vignetting"}): full + small,
            frozenset({"fpn_pattern", "vignetting"}): full + 300,
            frozenset({"fpn_pattern", "cyclic_error"}): full + 400,
            frozenset({"vignetting"}): full + small + 100,
            frozenset({"cyclic_error"}): full + small + 200,
        },
    )
    model = _Stub(["fpn_pattern", "cyclic_error", "vignetting"])
    out, effects = R.prune(model, _effects("fpn_pattern", "cyclic_error", "vignetting"), None, None)
    assert [e["name"] for e in effects] == ["vignetting", "cyclic_error"]
    assert sorted(out.effects) == ["cyclic_error", "vignetting"]


def test_every_term_needed_keeps_the_forward_order_when_it_is_right(monkeypatch):
    _patch(
        monkeypatch,
        {
            frozenset({"a", "b"}): 0.0,
            frozenset({"a"}): 50.0,
            frozenset({"b"}): 500.0,
        },
    )
    _, effects = R.prune(_Stub(["a", "b"]), _effects("a", "b"), None, None)
    assert [e["name"] for e in effects] == ["a", "b"]


def test_cached_scene_relay_equals_the_term_and_keeps_the_gradient():
    # predict() relays the two cached unit images once and scales them (the relay is linear in
    # the samples); it must equal Multipath.apply on the photons' samples, gradient included
    from dataclasses import replace

    import torch

    from tof_fpn_torch.diagnosis.terms import multipath as M
    from tof_fpn_torch.sim import Camera, Multipath, SimState, synthetic_scene
    from tof_fpn_torch.sim.readout import Photons

    cam = Camera()
    scene = synthetic_scene(24, 32, seed=3, depth_range=(0.6, 5.0))
    act = (
        Photons(responsivity=1.0).mean_samples(replace(cam, ambient_irradiance=0.0), scene).double()
    )
    amb = (
        Photons(responsivity=1.0)
        .mean_samples(replace(cam, illumination_power=0.0, ambient_irradiance=1.0), scene)
        .double()
    )
    resp = torch.tensor(1.7, dtype=torch.float64, requires_grad=True)
    relay = torch.tensor(0.05, dtype=torch.float64, requires_grad=True)
    free = torch.rand(24, 32, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    terms = (
        Multipath(0.01, 1.5, scene_relay=relay, field_of_view=60.0, near_field=1.0),
        # the member's form: free sources, both obliquities
        Multipath(
            scene_relay=torch.tensor(5.0, dtype=torch.float64, requires_grad=True),
            near_field=0.2,
            source_map=free,
            cosines=True,
        ),
    )
    for term in terms:
        M._RELAY_CACHE.clear()
        outs = []
        for cached in (True, False):
            samples = (act + amb * 0.8) * resp
            state = SimState(cam, scene, samples, None)
            if cached:
                out = M.relay_cached(term, state, (act, amb), ("test",), 0.8, resp).samples
            else:
                out = term.apply(state).samples
            (g_resp, g_relay) = torch.autograd.grad(out.sum(), (resp, term.scene_relay))
            outs.append((out.detach(), g_resp, g_relay))
        assert len(M._RELAY_CACHE) == 1
        (a, ga, ra), (b, gb, rb) = outs
        assert float((a - b).abs().max()) <= 1e-9 * float(b.abs().max())
        assert float((a - (act + amb * 0.8) * 1.7).abs().max()) > 1e-3 * float(b.abs().max())
        assert float(ga) == pytest.approx(float(gb), rel=1e-9)
        assert float(ra) == pytest.approx(float(rb), rel=1e-9)


def test_candidates_map_in_threads_keeps_the_order_and_the_thread_count():
    import threading
    import time

    import torch

    from tof_fpn_torch.diagnosis.threads import map_threads

    old = torch.get_num_threads()
    seen = set()

    def fn(x):
        seen.add(threading.get_ident())
        assert torch.get_num_threads() == 1  # one torch thread per Python thread
        return torch.full((64, 64), float(x)).matmul(torch.eye(64)).sum().item()

    try:
        torch.set_num_threads(2)
        got = map_threads(fn, list(range(12)))
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(old)
    assert got == [64.0 * 64.0 * x for x in range(12)]
    assert len(seen) >= 1 and threading.get_ident() not in seen  # ran in the pool
    started = []
    try:
        torch.set_num_threads(2)

        def slow(x):  # long enough that both threads have started before either is done
            started.append(x)
            time.sleep(0.05)
            return x * 10

        got = map_threads(slow, [1, 2, 3, 4], first=lambda x: x > 2)
    finally:
        torch.set_num_threads(old)
    assert got == [10, 20, 30, 40] and set(started[:2]) == {3, 4}
    torch.set_num_threads(1)
    try:
        assert map_threads(lambda x: x + 1, [1, 2]) == [2, 3]  # one thread: a plain loop
    finally:
        torch.set_num_threads(old)
