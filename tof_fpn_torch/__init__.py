"""tof_fpn_torch: fixed-pattern-noise suppression for Time-of-Flight depth data.

Layers (docs/architecture.md), each a subpackage that may import only the ones below it:

- :mod:`.constants` -- the paper's numbers and the defaults (standard library only);
- :mod:`.runtime` -- the torch-only stage: :class:`FPNFilter`, :class:`AmplitudeFusion`,
  :class:`FPNSuppression`, and the validity rule :func:`valid_mask`;
- :mod:`.denoise` -- torch-only denoisers (:class:`NonLocalMeans`);
- :mod:`.design` -- offline NumPy filter design (:func:`design_fpn`);
- :mod:`.analysis` -- metrics (:func:`psnr`) and stripe estimation (:func:`estimate_stripes`);
- :mod:`.sim` -- the raw-level simulator;
- :mod:`.build` -- run-time modules from a design or from data (:func:`suppression_from_design`);
- :mod:`.io` -- the file layer: camera files, the recording / scene formats, :class:`FrameDataset`;
- :mod:`.clean` -- ``tof-fpn clean``: the pipeline over files, resumable, local or Ray;
- :mod:`.learn` -- the stage in front of a learned network; :mod:`.diagnosis` -- simulation vs.
  recording (``tof-fpn diagnose``);
- :mod:`.paper_data`, :mod:`.demo` -- the paper's synthetic test data and ``tof-fpn demo``;
- :mod:`.export`, :mod:`.cli` -- TorchScript / ONNX export, ``tof-fpn``.

The paper's reproduction, the benchmarks and the training experiment live beside the package
(``benchmarks/``, ``examples/`` in the repository), not in it.

The names below are loaded on first use, so ``import tof_fpn_torch.runtime`` loads torch only;
type checkers and IDEs see them through the ``TYPE_CHECKING`` imports, which list the same names
(``tests/test_builders_signatures.py`` checks that the two agree).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.2.0"

#: public name -> the module that defines it
_EXPORTS: dict[str, str] = {
    "AmplitudeFusion": "runtime",
    "FPNFilter": "runtime",
    "FPNSuppression": "runtime",
    "fpn_filter": "runtime",
    "valid_mask": "runtime",
    "NonLocalMeans": "denoise",
    "non_local_means": "denoise",
    "FPNDesign": "design",
    "RemezConvergenceError": "design",
    "design_fpn": "design",
    "design_fpn_filter": "design",
    "StripeComponent": "analysis",
    "StripeEstimate": "analysis",
    "estimate_stripes": "analysis",
    "psnr": "analysis",
    "filter_from_design": "build",
    "suppression_from_data": "build",
    "suppression_from_design": "build",
    "fusion_from_data": "build",
    "broadband_from_data": "build",
    "Destripe": "runtime",
    "destripe": "runtime",
    "Camera": "sim",
    "Scene": "sim",
    "Simulation": "sim",
    "planar_scene": "sim",
    "synthetic_scene": "sim",
    "FrameDataset": "io",
    "Recording": "io",
    "SceneData": "io",
    "read_pair": "io",
    "read_recording": "io",
    "read_scene": "io",
    "write_pair": "io",
    "write_recording": "io",
    "write_scene": "io",
}
_MODULES: dict[str, str] = {"metrics": "analysis.metrics"}
_SUBPACKAGES = (
    "analysis",
    "build",
    "cameras",
    "clean",
    "cli",
    "constants",
    "demo",
    "denoise",
    "design",
    "diagnosis",
    "export",
    "io",
    "learn",
    "paper_data",
    "runtime",
    "sim",
)

__all__ = sorted([*_EXPORTS, *_MODULES, *_SUBPACKAGES, "__version__"])

if TYPE_CHECKING:  # the same names, imported eagerly, for type checkers and IDEs only
    # (``X as X``: an explicit re-export, PEP 484). ``destripe`` and ``fpn_filter`` come from
    # their own modules: type checkers take ``runtime.destripe`` for the submodule of that name.
    from . import analysis as analysis
    from . import build as build
    from . import cameras as cameras
    from . import clean as clean
    from . import cli as cli
    from . import constants as constants
    from . import demo as demo
    from . import denoise as denoise
    from . import design as design
    from . import diagnosis as diagnosis
    from . import export as export
    from . import io as io
    from . import learn as learn
    from . import paper_data as paper_data
    from . import runtime as runtime
    from . import sim as sim
    from .analysis import StripeComponent as StripeComponent
    from .analysis import StripeEstimate as StripeEstimate
    from .analysis import estimate_stripes as estimate_stripes
    from .analysis import metrics as metrics
    from .analysis import psnr as psnr
    from .build import broadband_from_data as broadband_from_data
    from .build import filter_from_design as filter_from_design
    from .build import fusion_from_data as fusion_from_data
    from .build import suppression_from_data as suppression_from_data
    from .build import suppression_from_design as suppression_from_design
    from .denoise import NonLocalMeans as NonLocalMeans
    from .denoise import non_local_means as non_local_means
    from .design import FPNDesign as FPNDesign
    from .design import RemezConvergenceError as RemezConvergenceError
    from .design import design_fpn as design_fpn
    from .design import design_fpn_filter as design_fpn_filter
    from .io import FrameDataset as FrameDataset
    from .io import Recording as Recording
    from .io import SceneData as SceneData
    from .io import read_pair as read_pair
    from .io import read_recording as read_recording
    from .io import read_scene as read_scene
    from .io import write_pair as write_pair
    from .io import write_recording as write_recording
    from .io import write_scene as write_scene
    from .runtime import AmplitudeFusion as AmplitudeFusion
    from .runtime import Destripe as Destripe
    from .runtime import FPNFilter as FPNFilter
    from .runtime import FPNSuppression as FPNSuppression
    from .runtime import valid_mask as valid_mask
    from .runtime.destripe import destripe as destripe
    from .runtime.fpn_filter import fpn_filter as fpn_filter
    from .sim import Camera as Camera
    from .sim import Scene as Scene
    from .sim import Simulation as Simulation
    from .sim import planar_scene as planar_scene
    from .sim import synthetic_scene as synthetic_scene


def __getattr__(name: str):
    if name in _EXPORTS:
        value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    elif name in _MODULES:
        value = importlib.import_module(f".{_MODULES[name]}", __name__)
    elif name in _SUBPACKAGES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
