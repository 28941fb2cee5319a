r"""Builders: run-time modules from an offline design or from data (the layer above both).

The run-time package (:mod:`tof_fpn_torch.runtime`) takes filter taps and knows nothing of how they
were designed; the design package (:mod:`tof_fpn_torch.design`) produces taps and knows nothing of
torch. These factories join them: they design the taps (NumPy), or first estimate the
stripes in data (:mod:`tof_fpn_torch.analysis`), then build the torch modules and record on them
what the design was (``order``, ``rho``, ``notches``, which TorchScript and ONNX exports keep).
Every option is an explicit keyword parameter, checked before any design or estimate runs (a
``ValueError`` names the option, its value and what is allowed); the defaults the builders share
are the ``DEFAULT_*`` constants here.

Example:
    >>> stage = suppression_from_design(20, 0.14)
    >>> stage.filter.order, stage.filter.rho, stage.filter.taps.shape, stage.gate
    (20, 0.14, torch.Size([21]), True)
"""

from .broadband import AUTO_DESTRIPE_MIN_Z, AUTO_DESTRIPE_WIDTH, broadband_from_data
from .data import suppression_from_data
from .design import (
    DEFAULT_ADAPTIVE,
    DEFAULT_ALLOW_SHIFT,
    DEFAULT_BORDER,
    DEFAULT_COMPENSATE_DELAY,
    DEFAULT_DIM,
    DEFAULT_GATE,
    DEFAULT_TRAINABLE,
    DEFAULT_UNIT_DC,
    MAX_RIPPLE_DB,
    DesignRefused,
    filter_from_design,
    suppression_from_design,
    trainable_suppression,
)
from .fusion import fusion_from_data, fusion_from_noise

__all__ = [
    "DesignRefused",
    "AUTO_DESTRIPE_MIN_Z",
    "AUTO_DESTRIPE_WIDTH",
    "DEFAULT_ADAPTIVE",
    "DEFAULT_ALLOW_SHIFT",
    "DEFAULT_BORDER",
    "DEFAULT_COMPENSATE_DELAY",
    "DEFAULT_DIM",
    "DEFAULT_GATE",
    "DEFAULT_TRAINABLE",
    "DEFAULT_UNIT_DC",
    "MAX_RIPPLE_DB",
    "broadband_from_data",
    "filter_from_design",
    "fusion_from_data",
    "fusion_from_noise",
    "suppression_from_data",
    "suppression_from_design",
    "trainable_suppression",
]
