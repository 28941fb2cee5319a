r"""The denoisers by name: the one registry of the package (the CLI, ``tof-fpn clean``, Table II).

:data:`DENOISERS` maps a name to a factory ``factory(**options) -> nn.Module``; the built-in
entries are the module classes of :mod:`tof_fpn_torch.denoise`, whose ``forward(depth,
amplitude=None, sigma=None)`` takes (B, C, H, W) depth, an optional (B, 1, H, W) amplitude and an
optional noise level, and returns invalid pixels unchanged. :func:`register` adds one (``tof-fpn
clean``'s ``register_denoiser`` is this function, its ``DENOISERS`` this dict).

Names are case-insensitive and ``_`` and ``-`` are the same; a few aliases (``sliding-dct``,
``lpaici``, ...) map to the canonical names that :func:`names` lists. A registered name is also
found exactly as it was registered. :func:`get` checks the options against the factory's
signature (the one check; a factory taking ``**kwargs`` takes anything).

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

from .bilateral import Bilateral, JointBilateral
from .bm3d import BM3D
from .guided import Guided
from .hypbi import HypothesisBilateral
from .lpa_ici import LPAICI
from .nlm import NonLocalMeans
from .sliding_dct import SlidingDCT

__all__ = [
    "DENOISERS",
    "canonical",
    "describe",
    "get",
    "module_class",
    "names",
    "register",
    "scriptable",
]

#: name -> factory(**options) -> module ``(depth, amplitude=None, ...) -> depth``: the built-in
#: denoisers in the paper's order (NLM, BM3D, sDCT, HypBi, LPA-ICI), then the kornia-based filters,
#: then whatever :func:`register` adds
DENOISERS: dict[str, Callable[..., nn.Module]] = {
    "nlm": NonLocalMeans,
    "bm3d": BM3D,
    "sdct": SlidingDCT,
    "hypbi": HypothesisBilateral,
    "lpa-ici": LPAICI,
    "bilateral": Bilateral,
    "joint-bilateral": JointBilateral,
    "guided": Guided,
}

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
    if name in DENOISERS:
        return name
    key = name.strip().lower().replace("_", "-")
    key = _ALIASES.get(key, key)
    if key not in DENOISERS:
        raise ValueError(f"unknown denoiser {name!r}; choose one of {names()}")
    return key


def register(name: str, factory: Callable[..., nn.Module]) -> None:
    """Add a denoiser under ``name`` (``denoise = "<name>"`` in ``tof-fpn clean``'s
    configuration, ``--denoise <name>``); an existing name is replaced.

    ``factory(**options)`` gets the options (``tof-fpn clean``'s ``[denoise]`` table) and returns a
    module called as ``module(depth, amplitude)`` on (B, 1, H, W) depth (NaN invalid) and
    amplitude, returning depth with invalid pixels unchanged.

    Raises:
        ValueError: ``name`` is not an identifier, or is ``"none"`` (which means no denoiser), or
            ``factory`` is not callable.
    """
    if not isinstance(name, str) or not name.isidentifier() or name == "none":
        raise ValueError(f"name must be an identifier other than 'none', got {name!r}")
    if not callable(factory):
        raise ValueError(f"factory must be callable, got {type(factory).__name__}")
    DENOISERS[name] = factory


def names() -> list[str]:
    """The canonical names: the built-in denoisers in the paper's order first (NLM, BM3D, sDCT,
    HypBi, LPA-ICI), then the kornia-based filters, then the registered ones."""
    return list(DENOISERS)


def _check_options(key: str, factory: Callable[..., nn.Module], options: dict) -> None:
    """The options must be parameters of ``factory`` (unless it takes ``**kwargs`` or has no
    signature inspect can read)."""
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return
    if any(p.kind is p.VAR_KEYWORD for p in params.values()):
        return
    allowed = [p for p in params if p != "self"]
    bad = sorted(set(options) - set(allowed))
    if bad:
        raise ValueError(
            f"unknown option(s) of denoiser {key!r}: it has no parameter(s) {bad}; "
            f"allowed: {allowed}"
        )


def get(name: str, **kwargs) -> nn.Module:
    """A new module for ``name`` built with ``kwargs`` (the factory's parameters).

    Raises:
        ValueError: unknown name (the message lists :func:`names`), or a keyword the denoiser
            does not take (the message lists the ones it does), or a bad value.
    """
    key = _canonical(name)
    factory = DENOISERS[key]
    _check_options(key, factory, kwargs)
    return factory(**kwargs)


def canonical(name: str) -> str:
    """The canonical name of ``name`` or of its alias (``"Sliding_DCT"`` -> ``"sdct"``).

    Raises:
        ValueError: unknown name (the message lists :func:`names`).
    """
    return _canonical(name)


def module_class(name: str) -> Callable[..., nn.Module]:
    """The module class (factory) of ``name``, taking the constructor's keywords."""
    return DENOISERS[_canonical(name)]


def describe(name: str) -> str:
    """One line: the canonical name, the class and the first line of its docstring."""
    key = _canonical(name)
    factory = DENOISERS[key]
    doc = (inspect.getdoc(factory) or "").splitlines()
    return (
        f"{key}: {getattr(factory, '__name__', type(factory).__name__)} - {doc[0] if doc else ''}"
    )


def scriptable(name: str) -> bool:
    """Whether ``torch.jit.script`` compiles the module (kornia-based ones are not scriptable;
    registered factories are not known to be)."""
    key = _canonical(name)
    return key in _SCRIPTABLE and DENOISERS[key] is _BUILTIN[key]


#: the built-in entries, to tell a replaced one from the original
_BUILTIN: dict[str, Callable[..., nn.Module]] = dict(DENOISERS)
