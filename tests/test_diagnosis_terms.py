"""The catalogue of diagnosis terms: every registered term implements the whole interface of
``diagnosis.terms.base.Term``, every term is defined in its own module under
``diagnosis/terms/`` and registered once in ``diagnosis.catalogue``, and the shared machinery
never dispatches on a term's name.

The interface is checked on a small seeded recording of the diagnosis baseline's physics: each
term's starting values, its simulator term, that the hook it enters by is implemented and moves
the likelihood, and that its description for the report is finite JSON.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import json
import math
import pkgutil
from pathlib import Path

import pytest
import torch

import tof_fpn_torch.diagnosis as diagnosis
from tof_fpn_torch.diagnosis import catalogue
from tof_fpn_torch.diagnosis.catalogue import CATALOGUE, TERMS, VOCABULARY
from tof_fpn_torch.diagnosis.data import observe
from tof_fpn_torch.diagnosis.fit import evaluate, init_model
from tof_fpn_torch.diagnosis.likelihood import make_context
from tof_fpn_torch.diagnosis.params import from_u, to_u
from tof_fpn_torch.diagnosis.prediction import predict
from tof_fpn_torch.diagnosis.terms.base import ENTERS, Term
from tof_fpn_torch.io import Recording, SceneData
from tof_fpn_torch.sim import STAGE, Camera, PixelGain, Simulation, synthetic_scene
from tof_fpn_torch.sim.readout import ADC, Photons, ReadNoise, ReadoutFPN, ShotNoise
from tof_fpn_torch.sim.terms import SimState
from tof_fpn_torch.sim.terms import Term as SimTerm

DIAG = Path(diagnosis.__file__).parent
TERMS_DIR = DIAG / "terms"
STATISTICS = (
    {"depth_mean", "amp_mean", "depth_spread", "amp_spread"},
    {"column", "row", "depth", "depth_mod", "amplitude", "radius", "edge", "raw", "pixels"},
)


def _all_modules() -> None:
    for m in pkgutil.walk_packages(diagnosis.__path__, diagnosis.__name__ + "."):
        importlib.import_module(m.name)


def _subclasses(cls) -> set:
    out = set()
    for c in cls.__subclasses__():
        out |= {c} | _subclasses(c)
    return out


# --- registration -------------------------------------------------------------------------------


def test_every_term_is_one_module_under_terms_and_registered_once():
    _all_modules()
    # the shared bases of terms (base.py) are not terms themselves
    defined = {c for c in _subclasses(Term) if c.__module__ != Term.__module__}
    registered = [type(t) for t in TERMS]
    assert len(set(registered)) == len(registered), "a term is registered twice"
    assert set(CATALOGUE) == {t.name for t in TERMS} and len(CATALOGUE) == len(TERMS)
    assert defined == set(registered), f"defined but not registered: {defined - set(registered)}"
    for t in TERMS:
        assert type(t).__module__ == f"tof_fpn_torch.diagnosis.terms.{t.name}", t.name
    modules = {p.stem for p in TERMS_DIR.glob("*.py")} - {"__init__", "base"}
    assert modules == set(CATALOGUE), "every terms/<name>.py holds the term <name>"
    for name in modules:
        mod = importlib.import_module(f"tof_fpn_torch.diagnosis.terms.{name}")
        own = [
            c
            for _, c in inspect.getmembers(mod, inspect.isclass)
            if issubclass(c, Term) and c is not Term and c.__module__ == mod.__name__
        ]
        assert len(own) == 1, f"terms/{name}.py defines {len(own)} terms"


def test_the_catalogue_order_is_kept():
    # the order the candidates are tried in and the tie-break of equal scores: a new term goes
    # at the end
    assert VOCABULARY[:12] == (
        "cyclic_error",
        "amplitude_bias",
        "fpn_pattern",
        "vignetting",
        "temporal_drift",
        "noise_floor",
        "pixel_gain",
        "impulsive_pixels",
        "saturation",
        "flying_pixels",
        "phase_wrapping",
        "multipath",
    )
    assert set(catalogue.REVEALED_WITHOUT_SCENE) == {
        "fpn_pattern",
        "noise_floor",
        "noise_floor_tails",
        "impulsive_pixels",
        "temporal_drift",
        "temporal_drift_frames",
    }


def test_the_catalogue_says_how_to_add_a_term():
    doc = catalogue.__doc__
    for word in ("Term", "TERMS", "terms/<name>.py", "tests/test_diagnosis_terms.py"):
        assert word in doc, word
    assert Path(__file__).name == "test_diagnosis_terms.py"


def _code_strings(path: Path) -> list[tuple[int, str]]:
    """String constants of the code (docstrings are prose)."""
    tree = ast.parse(path.read_text())
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docs.add(id(body[0].value))
    return [
        (n.lineno, n.value)
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs
    ]


def test_no_term_is_named_outside_its_module():
    """The shared machinery asks the terms through their hooks: no module of the diagnosis
    outside ``terms/`` writes a term's name or one of its parameter keys."""
    names = set(CATALOGUE)
    hits = []
    for path in sorted(DIAG.glob("*.py")):
        for line, s in _code_strings(path):
            if s in names or s.split(".")[0] in names and "." in s:
                hits.append(f"{path.name}:{line}: {s!r}")
    assert not hits, "dispatch on a term's name outside diagnosis/terms/:\n" + "\n".join(hits)


def test_the_name_scan_sees_a_dispatch(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text(
        '"""saturation in prose is fine."""\n'
        'def f(m, v):\n    """multipath too."""\n'
        '    if "saturation" in m.effects:\n        return v["noise_floor.sigma"]\n'
    )
    assert [s for _, s in _code_strings(probe)] == ["saturation", "noise_floor.sigma"]


# --- the interface, on a small recording --------------------------------------------------------


@pytest.fixture(scope="module")
def setup():
    """A 24 x 32, 4-frame recording of the baseline's physics with one weak row (so that every
    closed-form member finds something), its observations, the baseline from the data and the
    likelihood's context."""
    cam = Camera(integration_time=300e-6, adc_bits=16)
    fpn = ReadoutFPN(offset_amplitudes=(30.0, 20.0), gain_amplitudes=(0.0, 0.0))
    fpn.random_offset, fpn.random_gain = 0.0, 0.0
    row = torch.ones(24, 32, dtype=torch.float64)
    row[9] = 0.9
    terms = [Photons(), PixelGain(gain_map=row), ShotNoise(), fpn, ReadNoise(), ADC()]
    sim = Simulation(cam, terms)
    scene = synthetic_scene(24, 32, seed=5, depth_range=(0.6, 5.0))
    out = sim.run(scene, 4, seed=5)
    depth = torch.where(out.depth > 0, out.depth, torch.full_like(out.depth, math.nan))
    meta = {"modulation_frequency_hz": 20e6, "integration_time_us": 300.0, "n_phases": 4}
    rec = Recording(depth, out.amplitude, meta)
    obs = observe(rec, SceneData(scene.depth[0, 0], scene.reflectance[0, 0]))
    model = init_model(obs, obs.scene())
    with torch.no_grad():
        p = predict(model, obs)
    ctx = make_context(obs, p.a0 / p.s)
    return obs, model, ctx, scene


def test_every_term_declares_the_whole_interface():
    for t in TERMS:
        cls = type(t)
        assert t.name and isinstance(t.name, str), cls
        assert t.enters in ENTERS, (t.name, t.enters)
        assert t.about and t.axes, t.name
        for key in t.axes:
            channel, axis = key.split("|")
            assert channel in STATISTICS[0] | {"depth_frame", "amp_frame", "depth_tail"}, key
            assert axis in STATISTICS[1] | {"frame"}, key
        keys = [s.key for s in t.specs]
        assert len(set(keys)) == len(keys), t.name
        assert all(k.startswith(t.name + ".") for k in keys), t.name
        assert t.sim_name is None or t.sim_name in STAGE, t.name
        assert t.closed_form or t.specs, f"{t.name}: nothing to fit"
        for method in ("simulator_term", "initial_values", "describe"):
            assert getattr(cls, method) is not getattr(Term, method), f"{t.name}.{method}"
        hooks = {
            "variance": ("depth_variance", "depth_variance_limit", "amplitude_sd", "depth_mean_sd"),
            "frames": ("frame_means", "outlier_rate", "depth_tail"),
            "wrap": ("wrap_range",),
        }.get(t.enters, ())
        if hooks:
            assert any(getattr(cls, h) is not getattr(Term, h) for h in hooks), (t.name, hooks)


def _fingerprint(model, obs, ctx) -> tuple:
    """The NLL and the prediction of ``model`` (means, spreads, random effect, fold)."""
    with torch.no_grad():
        p = predict(model, obs, scene=ctx.scene)
    tau = p.tau_a if isinstance(p.tau_a, torch.Tensor) else torch.tensor(float(p.tau_a))
    return (evaluate(model, obs, ctx), p.mu_d, p.sd_d, p.mu_a, p.sd_a, tau, p.wrap)


def _differ(a: tuple, b: tuple) -> bool:
    if abs(a[0] - b[0]) > 1e-9 * abs(b[0]) or a[-1] != b[-1]:
        return True
    return any(
        not torch.allclose(x, y, rtol=1e-9, atol=0.0) for x, y in zip(a[1:-1], b[1:-1], strict=True)
    )


@pytest.mark.parametrize("name", list(CATALOGUE))
def test_term_starts_enters_the_model_and_is_described(setup, name):
    obs, model, ctx, scene = setup
    term = CATALOGUE[name]
    with torch.no_grad():
        pred = predict(model, obs, scene=ctx.scene)
    starts = term.initial_values(model, obs, ctx, pred)
    assert starts, f"{name}: no starting value on a 4-frame recording"
    for v in starts:
        assert all(k.startswith(name + ".") for k in v), (name, v)
        assert {s.key for s in term.specs} <= set(v), (name, v)
        assert all(math.isfinite(float(x)) for x in v.values()), (name, v)
    m = model.with_effect(term, starts[0])
    if term.closed_form:
        with torch.no_grad():
            m = term.update_closed_form(m, obs, ctx, predict(m, obs, scene=ctx.scene), "all")
        assert set(term.profile_keys) <= set(m.profiles), name
        assert term.effective_parameters(m.values) > 0, name
        assert m.without(name).profiles == {} and m.without(name).effects == model.effects
    # the hook it enters by changes the prediction or the likelihood: at the start or half a
    # step either side of it
    ref = _fingerprint(model, obs, ctx)
    moves = [m]
    for step in (0.5, -0.5):
        moved = m.copy()
        for s in term.specs:
            moved.values[s.key] = from_u(s, to_u(s, m.values[s.key]) + step)
        moves.append(moved)
    prints = [_fingerprint(x, obs, ctx) for x in moves]
    assert all(math.isfinite(f[0]) for f in prints), name
    assert any(_differ(f, ref) for f in prints), f"{name} does not enter the model"
    # its simulator term (the complete, noisy model runs with it)
    st = term.simulator_term(m.values, m)
    if term.sim_name is None:
        assert st is None, name
    else:
        assert isinstance(st, SimTerm) and st.name == term.sim_name, (name, st)
    if term.enters == "chain":
        assert st is not None, f"{name} enters the chain without a simulator term"
    out = m.simulation().run(scene, 2, seed=1)
    assert bool(torch.isfinite(out.amplitude).all()), name
    # its description: finite numbers, JSON
    with torch.no_grad():
        p = predict(m, obs, scene=ctx.scene)
    desc = term.describe(m, obs, p)
    assert isinstance(desc, dict) and desc, name
    text = json.dumps(desc, allow_nan=False)
    assert json.loads(text) == desc


def test_two_forms_of_one_effect_make_one_stage(setup):
    """A model holding an effect in two forms (the physical term and a flexible member, same
    simulator stage) exports one Simulation whose stage applies both in turn: its noise-free
    run equals the two simulator terms applied one after the other."""
    from tof_fpn_torch.sim import Joined

    obs, model, ctx, scene = setup
    for member in [t for t in TERMS if t.signature and t.enters == "chain"]:
        phys = CATALOGUE[member.effect]
        m = model
        for term in (phys, member):
            with torch.no_grad():
                pred = predict(m, obs, scene=ctx.scene)
            m = m.with_effect(term, term.initial_values(m, obs, ctx, pred)[0])
            if term.closed_form:
                with torch.no_grad():
                    pred = predict(m, obs, scene=ctx.scene)
                m = term.update_closed_form(m, obs, ctx, pred, "all")
        sim = m.simulation()
        joined = [t for t in sim.terms if isinstance(t, Joined)]
        assert len(joined) == 1 and joined[0].name == phys.sim_name, member.name
        a = phys.simulator_term(m.values, m)
        b = member.simulator_term(m.values, m)
        h, w = scene.depth.shape[-2:]  # the scene's size: a relay needs its geometry
        s = torch.rand(1, 4, h, w, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
        s = 500.0 + 300.0 * s
        one = joined[0].apply(SimState(m.camera, scene, s.clone(), None)).samples
        two = b.apply(a.apply(SimState(m.camera, scene, s.clone(), None))).samples
        assert torch.equal(one, two), member.name
        # and model.json holds it: the stage's parts written as terms, the model read back
        import json

        from tof_fpn_torch.diagnosis.persist import load_model, model_to_dict

        data = json.loads(json.dumps(model_to_dict(m)))
        stage = next(t for t in data["simulation"] if t["term"] == "Joined")
        assert [p["term"] for p in stage["parts"]] == [type(a).__name__, type(b).__name__]
        back = load_model(data)
        assert back.effects == m.effects and back.values == pytest.approx(m.values), member.name


def test_hessian_hint_fills_the_known_block():
    """The whitening's Hessian with a known block (the core parameters' from the current model)
    equals the full finite-difference Hessian: the known rows come from the block, their
    entries against the other keys from the computed rows (by symmetry)."""
    from tof_fpn_torch.diagnosis.fit import _hessian

    g = torch.Generator().manual_seed(2)
    m = torch.randn(5, 5, dtype=torch.float64, generator=g)
    a = m @ m.T + 5 * torch.eye(5, dtype=torch.float64)

    def objective(u):
        return 0.5 * u @ a @ u

    u0 = torch.randn(5, dtype=torch.float64, generator=g)
    _, full = _hessian(objective, u0)
    idx = [0, 2, 3]
    _, hinted = _hessian(objective, u0, (idx, a[idx][:, idx]))
    assert torch.allclose(full, a, atol=1e-6)
    assert torch.allclose(hinted, a, atol=1e-6)
    wrong = (idx, torch.zeros(3, 3, dtype=torch.float64))  # the block is taken as given
    _, h0 = _hessian(objective, u0, wrong)
    assert torch.allclose(h0[[1, 4]][:, [1, 4]], a[[1, 4]][:, [1, 4]], atol=1e-6)
    assert float(h0[0, 0]) == 0.0


@pytest.mark.parametrize("all_valid", [True, False])
def test_pixel_stats_match_numpy(all_valid):
    """Count, mean and sum of squared deviations over the valid frames of each pixel, against
    NumPy's masked mean and variance (both paths: every frame valid, and some not)."""
    import numpy as np

    from tof_fpn_torch.diagnosis.data import pixel_stats

    g = torch.Generator().manual_seed(5)
    x = torch.randn(9, 6, 7, dtype=torch.float64, generator=g) * 3 + 1
    valid = torch.rand(9, 6, 7, generator=g) > (0.0 if all_valid else 0.3)
    valid[0] = True  # every pixel has a frame
    n, m, m2 = pixel_stats(x, valid)
    xm = np.ma.masked_array(x.numpy(), mask=~valid.numpy())
    np.testing.assert_array_equal(n.numpy(), valid.sum(0).numpy())
    np.testing.assert_allclose(m.numpy(), xm.mean(0).filled(), rtol=1e-12)
    np.testing.assert_allclose(m2.numpy(), (xm.var(0) * valid.sum(0).numpy()).filled(), rtol=1e-10)


def test_edge_mixture_folds_the_depth_as_the_pooled_likelihood_does():
    """With a stated shorter range (phase wrapping) the far side of an edge reads its depth
    folded; the edge pixels' mixture must start from the same folded residual as their pooled
    NLL (its cost at share 0 is that NLL). Data that are exactly the unmixed prediction: the
    mixture changes the NLL by about its probability, not by a huge negative amount (a residual
    folded by the camera's range only there made it fall without bound as the noise shrank)."""
    from types import SimpleNamespace

    from tof_fpn_torch.diagnosis.likelihood import _edge_mixture

    h, w, n, wrap = 6, 8, 24.0, 2.0
    f64 = torch.float64
    depth = torch.full((h, w), 1.0, dtype=f64)
    depth[:, w // 2 :] = 2.5  # beyond the stated range: reads 0.5
    full = torch.ones(h, w, dtype=torch.bool)
    sd_d, sd_a, amp = 1e-4, 1.0, 100.0

    def const(v):
        return torch.full((h, w), v, dtype=f64)

    obs = SimpleNamespace(
        scene_depth=depth,
        n=const(n),
        m_d=torch.remainder(depth, wrap),
        m2_d=const((n - 1) * sd_d**2),
        m_a=const(amp),
        m2_a=const((n - 1) * sd_a**2),
    )
    ctx = SimpleNamespace(_frames={}, mask_d=full, mask_a=full, select=lambda sel: full)
    pred = SimpleNamespace(
        mu_d=depth,
        a0=const(amp),
        mu_a=const(amp),
        sd_d=const(sd_d),
        sd_a=const(sd_a),
        tau_d=0.0,
        tau_a=0.0,
        s=const(1.0),
        wrap=torch.tensor([wrap], dtype=f64),  # as a fitted value is
    )
    change = float(_edge_mixture(obs, ctx, pred, 1e-6, "all", 20e6))
    assert abs(change) < 1e-3, change
