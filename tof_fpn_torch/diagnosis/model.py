"""The diagnosing model: a simulator chain whose noise-free output is the mean, plus the noise law.

Baseline: ideal sinusoidal correlation (:class:`~tof_fpn_torch.sim.Photons`, amplitude
``k rho cos(theta_inc)^gamma / d^2`` up to the camera constants, ``k`` = ``photons.responsivity``
fitted; ``gamma`` = ``photons.incidence``, 1 for a scene whose reflectance is an albedo, else 0,
chosen from the amplitude before the fit, :mod:`~tof_fpn_torch.diagnosis.incidence`), offset ``B``
(active light over the demodulation contrast plus ambient), photon shot and read noise (the
conversion gain ``g`` and the read noise fitted), column read-out FPN at ``2 pi / 3`` and ``pi``
(:class:`~tof_fpn_torch.sim.ReadoutFPN`'s offsets ``o_n(x) = p(x) cos(2 pi n / N - psi)``; the
three signed amplitudes of ``p`` and ``psi`` fitted). No saturation, no wrapping.

The model holds the catalogue terms it has (instances of
:class:`~tof_fpn_torch.diagnosis.terms.base.Term`, given to it by
:meth:`DiagnosisModel.with_effect`) and asks them through the hooks of ``Term``, never by name.
Its prediction for every pixel is :func:`~tof_fpn_torch.diagnosis.prediction.predict` (also
importable from here).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from .. import constants as K
from ..sim import ADC, STAGE, Camera, Joined, Photons, ReadNoise, ReadoutFPN, ShotNoise, Simulation
from .incidence import FOV_KEY, INCIDENCE_KEY, IncidentPhotons
from .params import ParamSpec
from .prediction import WRAP_BOUNDARY_SD, Prediction, dev_to_boundary, predict
from .readout import READOUT_KEYS, readout_maps
from .terms.base import Term

__all__ = [
    "CORE_SPECS",
    "WRAP_BOUNDARY_SD",
    "DiagnosisModel",
    "Prediction",
    "dev_to_boundary",
    "predict",
]

#: always fitted
CORE_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("photons.responsivity", "log", 1.0, charge=True),
    ParamSpec("camera.conversion_gain", "log", 1.0, "e-/DN"),
    ParamSpec("camera.read_noise", "rootabs", 1.0, "e-", charge=True),
    ParamSpec("camera.ambient_irradiance", "abs", 0.1, "W/m^2"),
    ParamSpec("readout_fpn.cos_2pi3", "lin", 1.0, "e-", charge=True),
    ParamSpec("readout_fpn.sin_2pi3", "lin", 1.0, "e-", charge=True),
    ParamSpec("readout_fpn.cos_pi", "lin", 1.0, "e-", charge=True),
    ParamSpec("readout_fpn.sample_phase", "lin", 1.0, "rad"),
)


@dataclass
class DiagnosisModel:
    """Camera, fitted values (``"owner.field"`` -> float), the catalogue terms in the model
    (``terms``: :class:`~tof_fpn_torch.diagnosis.terms.base.Term` instances, in the order they
    were added; ``effects``: their names), the closed-form profiles (``"columns"``, ``"rows"``,
    the baseline's read-out columns), the keys of values the recording states (``fixed``: not
    fitted) and whether the baseline holds random column read-out offsets and gains
    (``random_columns``, :mod:`~tof_fpn_torch.diagnosis.readout`)."""

    camera: Camera
    values: dict
    terms: list[Term] = field(default_factory=list)
    profiles: dict = field(default_factory=dict)
    frame_interval: float = 1.0
    impulsive_level: float = 1e-6
    fpn_scale: float = 1.0
    fixed: frozenset = frozenset()
    random_columns: bool = False

    def copy(self) -> DiagnosisModel:
        return DiagnosisModel(
            replace(self.camera),
            dict(self.values),
            list(self.terms),
            {k: v.clone() for k, v in self.profiles.items()},
            self.frame_interval,
            self.impulsive_level,
            self.fpn_scale,
            self.fixed,
            self.random_columns,
        )

    @property
    def effects(self) -> tuple[str, ...]:
        """The names of the terms in the model, in the order they were added."""
        return tuple(t.name for t in self.terms)

    def wrap_range(self, v: dict | None = None):
        """The range (m) a term of the model folds the depth into (None: no folding)."""
        v = self.values if v is None else v
        for t in self.terms:
            r = t.wrap_range(v)
            if r is not None:
                return r
        return None

    def specs(self) -> list[ParamSpec]:
        """Every fitted scalar of the model (core + its effects)."""
        out = []
        for s in CORE_SPECS:
            if s.key in self.fixed:
                continue
            if s.key.startswith(("readout_fpn.cos", "readout_fpn.sin")):
                s = replace(s, scale=self.fpn_scale)
            elif s.key == "camera.read_noise":
                s = replace(s, scale=self.fpn_scale**2)
            out.append(s)
        for t in self.terms:
            out.extend(s for s in t.specs if s.key not in self.fixed)
        return out

    def n_parameters(self) -> float:
        """Number of fitted parameters (closed-form estimates count their effective degrees of
        freedom, ``Term.effective_parameters``)."""
        extra = sum((t.effective_parameters(self.values) for t in self.terms), 0.0)
        # the read-out columns count once: as a term's profiles, or as the baseline's own
        owned = any(set(READOUT_KEYS) & set(t.profile_keys) for t in self.terms)
        if READOUT_KEYS[0] in self.profiles and not owned:
            extra += float(self.values.get("readout_fpn.columns_dof", 0.0))
        return len(self.specs()) + extra

    def with_effect(self, term: Term, init: dict) -> DiagnosisModel:
        """A copy with ``term`` (a catalogue term, e.g. ``CATALOGUE["cyclic_error"]``) added
        at the end (kept in its place when a term of its name is in the model) and the values
        ``init``."""
        if not isinstance(term, Term):
            raise TypeError(
                f"with_effect takes a diagnosis term (e.g. CATALOGUE[{term!r}]), got {term!r}"
            )
        m = self.copy()
        if term.name not in m.effects:
            m.terms.append(term)
        m.values.update(init)
        return m

    def without(self, name: str) -> DiagnosisModel:
        """A copy without the term named ``name`` (its values and profiles dropped)."""
        m = self.copy()
        gone = [t for t in m.terms if t.name == name]
        m.terms = [t for t in m.terms if t.name != name]
        m.values = {k: v for k, v in m.values.items() if not k.startswith(name + ".")}
        for k in (k for t in gone for k in t.profile_keys):
            m.profiles.pop(k, None)
        return m

    def readout_fpn(self) -> ReadoutFPN:
        """The baseline FPN as the simulator's :class:`ReadoutFPN` (amplitude >= 0, phases)."""
        v = self.values
        a2 = math.hypot(v["readout_fpn.cos_2pi3"], v["readout_fpn.sin_2pi3"])
        th2 = math.atan2(v["readout_fpn.sin_2pi3"], v["readout_fpn.cos_2pi3"])
        cpi = v["readout_fpn.cos_pi"]
        off, gain = readout_maps(self, self.camera.n_phases, float(v["camera.conversion_gain"]))
        return ReadoutFPN(
            frequencies=K.FPN_FREQUENCIES,
            offset_amplitudes=(a2, abs(cpi)),
            gain_amplitudes=(0.0, 0.0),
            spatial_phases=(th2, 0.0 if cpi >= 0 else math.pi),
            sample_phase=v["readout_fpn.sample_phase"],
            random_offset=0.0,
            random_gain=0.0,
            offset_map=off,
            gain_map=gain,
        )

    def simulation_camera(self) -> Camera:
        f = float(self.camera.modulation_frequency)
        wrap = self.wrap_range()
        if wrap is not None:
            f = K.SPEED_OF_LIGHT_AIR / (2.0 * wrap)
        return replace(
            self.camera,
            full_well=1e30,  # the model has no saturation unless `saturation` is in it
            adc_bits=32,
            modulation_frequency=f,
            conversion_gain=self.values["camera.conversion_gain"],
            read_noise=self.values["camera.read_noise"],
            ambient_irradiance=self.values.get("camera.ambient_irradiance", 0.1),
        )

    def simulation(self) -> Simulation:
        """The model as a complete, noisy :class:`~tof_fpn_torch.sim.Simulation` (DN out)."""
        v = self.values
        gamma = float(v.get(INCIDENCE_KEY, 0.0))
        photons = (
            IncidentPhotons(v["photons.responsivity"], incidence=gamma, field_of_view=v[FOV_KEY])
            if gamma > 0.0 and FOV_KEY in v
            else Photons(responsivity=v["photons.responsivity"])
        )
        terms = [photons, ShotNoise(), self.readout_fpn()]
        terms += [ReadNoise(), ADC(quantize=True)]
        for term in self.terms:
            t = term.simulator_term(v, self)
            if t is None:
                continue
            same = next((i for i, x in enumerate(terms) if x.name == t.name), None)
            if same is None:
                terms.append(t)
            else:  # two forms of one effect: one stage, applied in turn
                prev = terms[same]
                parts = prev.parts if isinstance(prev, Joined) else (prev,)
                terms[same] = Joined(parts + (t,), t.name)
        terms.sort(key=lambda t: STAGE.get(t.name, 50))
        return Simulation(self.simulation_camera(), terms)
