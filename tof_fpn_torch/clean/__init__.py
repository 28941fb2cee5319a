"""``tof-fpn clean``: the FPN pipeline over a file, a directory tree or an HDF5 file, safely.

May import: torch, NumPy, tqdm, Ray (``ray``, optional, only by :mod:`.ray_engine` when the Ray
engine runs), the standard library and the layers :mod:`~tof_fpn_torch.runtime`,
:mod:`~tof_fpn_torch.build`, :mod:`~tof_fpn_torch.denoise`, :mod:`~tof_fpn_torch.io`,
:mod:`~tof_fpn_torch.cameras`, :mod:`~tof_fpn_torch.analysis`, :mod:`~tof_fpn_torch.constants`.
docs/clean.md describes the command, the configuration, the safety design and the measurements.

- :mod:`.config` -- :class:`CleanConfig`, the TOML format (:func:`load_config`);
- :mod:`.steps` -- the steps, one file each, and their registry (:func:`.steps.register`);
- :mod:`.pipeline` -- :class:`CleanPipeline` (the built stages in order), the denoiser registry;
- :mod:`.plan` -- jobs, INPUT / OUTPUT checks, temporary names;
- :mod:`.work` -- load / compute / write one group of files (shared by the engines);
- :mod:`.manifest` -- ``manifest.jsonl`` and resuming;
- :mod:`.run` -- :func:`clean`, a whole run; :mod:`.local`, :mod:`.ray_engine` -- the engines.

Example:
    >>> from tof_fpn_torch.clean import CleanConfig
    >>> CleanConfig(notch="design", denoise="nlm").fusion
    'camera'
"""

from .config import CleanConfig, choices, config_from_dict, config_to_toml, load_config, reference
from .pipeline import (
    DENOISERS,
    Calibration,
    CleanPipeline,
    build_pipeline,
    describe,
    register_denoiser,
)
from .run import ENGINES, CleanReport, clean, resolve_device

__all__ = [
    "DENOISERS",
    "ENGINES",
    "Calibration",
    "CleanConfig",
    "CleanPipeline",
    "CleanReport",
    "build_pipeline",
    "choices",
    "clean",
    "config_from_dict",
    "config_to_toml",
    "describe",
    "load_config",
    "reference",
    "register_denoiser",
    "resolve_device",
]
