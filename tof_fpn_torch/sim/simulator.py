"""The raw-level simulator: a camera plus a list of named terms, run on a scene."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch

from .camera import Camera, depth_from_samples
from .readout import default_terms
from .scenes import Scene
from .terms import SimState, Term

__all__ = ["SimResult", "Simulation", "simulate"]


@dataclass
class SimResult:
    """Output of :meth:`Simulation.run`; every map is (B, 1, H, W) except ``samples``.

    Attributes:
        samples: (B, N, H, W) correlation samples (DN after the ADC term, else e-).
        depth: metres, eq. (1); 0 where all samples are equal (dead pixels).
        amplitude, offset: in the unit of ``samples``.
        saturated, impulsive: bool masks (all False when the chain lacks the term).
        unit: ``"DN"`` or ``"e-"``.
    """

    samples: torch.Tensor
    depth: torch.Tensor
    amplitude: torch.Tensor
    offset: torch.Tensor
    saturated: torch.Tensor
    impulsive: torch.Tensor
    unit: str


@dataclass
class Simulation:
    """A ToF capture model: ``camera`` settings and the ordered list of physical ``terms``.

    Parameters are plain fields: ``sim.camera.integration_time = 50e-6``,
    ``sim.term("readout_fpn").offset_amplitudes = (10.0, 5.0)``, or in bulk with
    :meth:`parameters` / :meth:`set_parameters` using ``"camera.<field>"`` and
    ``"<term name>.<field>"`` keys (what a fit to recordings changes).

    Example::

        sim = Simulation(Camera(integration_time=100e-6))
        out = sim.run(synthetic_scene(), frames=10, seed=0)   # out.depth: (10, 1, 204, 204)
    """

    camera: Camera = field(default_factory=Camera)
    terms: list = field(default_factory=default_terms)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> Simulation:
        if not isinstance(self.camera, Camera):
            raise ValueError(f"camera must be a Camera, got {type(self.camera).__name__}")
        self.camera.validate()
        names = []
        for t in self.terms:
            if not isinstance(t, Term):
                raise ValueError(f"terms must be Term instances, got {type(t).__name__}")
            t.validate()
            names.append(t.name)
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"term names must be unique, got duplicates {dup} in {names}")
        return self

    def term(self, name: str) -> Term:
        """The term called ``name`` (e.g. ``"readout_fpn"``)."""
        for t in self.terms:
            if t.name == name:
                return t
        raise ValueError(f"no term named {name!r}; terms are {[t.name for t in self.terms]}")

    def without(self, *names: str) -> Simulation:
        """A copy without the named terms (e.g. ``sim.without("shot_noise", "read_noise")``)."""
        for nm in names:
            self.term(nm)
        return Simulation(
            dataclasses.replace(self.camera),
            [dataclasses.replace(t) for t in self.terms if t.name not in names],
        )

    def parameters(self) -> dict:
        """All numeric parameters as ``{"camera.<field>" | "<term>.<field>": value}``."""
        out = {f"camera.{k}": v for k, v in self.camera.as_dict().items()}
        for t in self.terms:
            out.update({f"{t.name}.{k}": v for k, v in t.parameters().items()})
        return out

    def set_parameters(self, **values) -> Simulation:
        """Set parameters by ``"owner.field"`` key (pass as ``**{"camera.read_noise": 5.0}``)."""
        for key, value in values.items():
            owner, _, fld = key.partition(".")
            obj = self.camera if owner == "camera" else self.term(owner)
            if not fld or not hasattr(obj, fld) or fld == "name":
                raise ValueError(f"unknown parameter {key!r}; known: {sorted(self.parameters())}")
            setattr(obj, fld, value)
        return self.validate()

    def run(
        self,
        scene: Scene,
        frames: int = 1,
        *,
        seed: int | None = None,
        generator: torch.Generator | None = None,
    ) -> SimResult:
        """Simulate ``frames`` captures of every scene in the batch.

        Args:
            scene: :class:`Scene` with B scenes; its device and dtype are used throughout.
            frames: captures per scene (>= 1); the output batch is ``B * frames``, frame ``f`` of
                scene ``b`` at index ``b * frames + f``. The read-out FPN is the same in all.
            seed: seeds a new generator on the scene's device (default 0) ...
            generator: ... or pass one (on the scene's device); not both.

        Returns:
            :class:`SimResult`.
        """
        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a Scene, got {type(scene).__name__}")
        scene.validate()
        self.validate()
        if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
            raise ValueError(f"frames must be an int >= 1, got {frames!r}")
        if seed is not None and generator is not None:
            raise ValueError("pass seed or generator, not both")
        device = scene.depth.device
        if generator is None:
            s = 0 if seed is None else seed
            if isinstance(s, bool) or not isinstance(s, int) or s < 0:
                raise ValueError(f"seed must be an int >= 0, got {seed!r}")
            generator = torch.Generator(device=device).manual_seed(s)
        elif generator.device.type != device.type:
            raise ValueError(
                f"generator is on {generator.device}, the scene on {device}; they must match"
            )
        b, _, h, w = scene.shape
        state = SimState(
            camera=self.camera,
            scene=scene,
            samples=torch.zeros(
                (b, self.camera.n_phases, h, w), device=device, dtype=scene.depth.dtype
            ),
            generator=generator,
        )
        state.frames = frames
        for t in self.terms:
            state = t.apply(state)
        state.expand()
        depth, amp, off = depth_from_samples(state.samples, float(self.camera.modulation_frequency))
        zeros = torch.zeros_like(depth, dtype=torch.bool)
        return SimResult(
            samples=state.samples,
            depth=depth,
            amplitude=amp,
            offset=off,
            saturated=zeros if state.saturated is None else state.saturated.expand_as(zeros),
            impulsive=zeros if state.impulsive is None else state.impulsive.expand_as(zeros),
            unit=state.unit,
        )


def simulate(
    scene: Scene,
    camera: Camera | None = None,
    terms: list | None = None,
    *,
    frames: int = 1,
    seed: int = 0,
) -> SimResult:
    """One-call form: ``Simulation(camera, terms).run(scene, frames, seed=seed)``."""
    sim = Simulation(
        Camera() if camera is None else camera, default_terms() if terms is None else terms
    )
    return sim.run(scene, frames, seed=seed)
