r"""The denoisers by name, for the CLI and ``tof-fpn clean``: :func:`get`, :func:`names`.

Every entry is an ``nn.Module`` whose ``forward(depth, amplitude=None, sigma=None)`` takes
(B, C, H, W) depth, an optional (B, 1, H, W) amplitude and an optional noise level, and returns
invalid pixels unchanged (:mod:`tof_fpn_torch.denoise`). Names are case-insensitive and ``_``
and ``-`` are the same; a few aliases (``sliding-dct``, ``lpaici``, ...) map to the canonical
names that :func:`names` lists.

Example:
    >>> from tof_fpn_torch import denoise
    >>> "bm3d" in denoise.names() and "nlm" in denoise.names()
    True
    >>> denoise.get("NLM", patch_size=5).patch_size
    5
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

from torch import nn

__all__ = ["canonical", "describe", "get", "module_class", "names", "scriptable"]


def _classes() -> dict[str, Callable[..., nn.Module]]:
    """Canonical name -> module class (imported here: the registry is the one index)."""
    from .bilateral import Bilateral, JointBilateral
    from .bm3d import BM3D
    from .guided import Guided
    from .hypbi import HypothesisBilateral
    from .lpa_ici import LPAICI
    from .nlm import NonLocalMeans
    from .sliding_dct import SlidingDCT

    out: dict[str, Callable[..., nn.Module]] = {
        "nlm": NonLocalMeans,
        "bm3d": BM3D,
        "sdct": SlidingDCT,
        "hypbi": HypothesisBilateral,
        "lpa-ici": LPAICI,
        "bilateral": Bilateral,
        "joint-bilateral": JointBilateral,
        "guided": Guided,
    }
    return out


#: alias -> canonical name (after lower-casing and ``_`` -> ``-``)
_ALIASES: dict[str, str] = {
    "non-local-means": "nlm",
    "nonlocalmeans": "nlm",
    "sliding-dct": "sdct",
    "slidingdct": "sdct",
    "dct": "sdct",
    "hypothesis-bilateral": "hypbi",
    "hypothesisbilateral": "hypbi",
    "lpaici": "lpa-ici",
    "jointbilateral": "joint-bilateral",
    "joint-bilateral-filter": "joint-bilateral",
    "guided-filter": "guided",
}

#: canonical names whose module ``torch.jit.script`` compiles
_SCRIPTABLE = {"nlm", "bm3d", "sdct", "hypbi", "lpa-ici"}


def _canonical(name: str) -> str:
    if not isinstance(name, str):
        raise ValueError(f"denoiser name must be a string, got {type(name).__name__}")
    key = name.strip().lower().replace("_", "-")
    key = _ALIASES.get(key, key)
    if key not in _classes():
        raise ValueError(f"unknown denoiser {name!r}; choose one of {names()}")
    return key


def names() -> list[str]:
    """The canonical names, in the paper's order first (NLM, BM3D, sDCT, HypBi, LPA-ICI), then the
    kornia-based filters."""
    order = ["nlm", "bm3d", "sdct", "hypbi", "lpa-ici", "bilateral", "joint-bilateral", "guided"]
    have = _classes()
    return [n for n in order if n in have]


def get(name: str, **kwargs) -> nn.Module:
    """A new module for ``name`` built with ``kwargs`` (the class's constructor parameters).

    Raises:
        ValueError: unknown name (the message lists :func:`names`), or a keyword the denoiser
            does not take (the message lists the ones it does), or a bad value.
    """
    key = _canonical(name)
    cls = _classes()[key]
    params = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    bad = sorted(set(kwargs) - set(params))
    if bad:
        raise ValueError(f"denoiser {key!r} has no parameter(s) {bad}; it takes {params}")
    return cls(**kwargs)


def canonical(name: str) -> str:
    """The canonical name of ``name`` or of its alias (``"Sliding_DCT"`` -> ``"sdct"``).

    Raises:
        ValueError: unknown name (the message lists :func:`names`).
    """
    return _canonical(name)


def module_class(name: str) -> Callable[..., nn.Module]:
    """The module class of ``name`` (a factory taking the constructor's keywords)."""
    return _classes()[_canonical(name)]


def describe(name: str) -> str:
    """One line: the canonical name, the class and the first line of its docstring."""
    key = _canonical(name)
    cls = _classes()[key]
    doc = (inspect.getdoc(cls) or "").splitlines()
    return f"{key}: {cls.__name__} - {doc[0] if doc else ''}"


def scriptable(name: str) -> bool:
    """Whether ``torch.jit.script`` compiles the module (kornia-based ones are not scriptable)."""
    return _canonical(name) in _SCRIPTABLE
