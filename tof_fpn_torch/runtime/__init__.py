"""Run-time FPN stage: torch (and kornia) only, TorchScript / ONNX exportable, CPU and CUDA.

May import: torch, kornia, the standard library, :mod:`tof_fpn_torch.constants`. Must not import
the offline design, the analysis, the simulator, NumPy, SciPy or matplotlib (``tests/test_layout.py``
checks this). The modules take filter taps; designing them is the job of :mod:`tof_fpn_torch.design`
and :mod:`tof_fpn_torch.build` (one layer up), which call into this package, never the reverse.

- :mod:`.validity`: the one validity rule (:func:`valid_mask`).
- :mod:`.noise`: every robust noise scale of the package (wavelet MAD, clipped mean, clipped RMS).
- :mod:`.fir`: 1-D FIR kernels (polyphase / block-Toeplitz GEMMs, borders).
- :mod:`.fpn_filter`: :func:`fpn_filter`, :class:`FPNFilter`.
- :mod:`.fusion`: :func:`amplitude_fusion`, :class:`AmplitudeFusion` (eq. 11).
- :mod:`.suppression`: :class:`FPNSuppression` (filter + fusion).
- :mod:`.destripe`: :func:`destripe`, :class:`Destripe` (broadband column / row offsets, one frame).
- :mod:`.fixed_pattern`: :class:`FixedPatternCorrection` (a calibrated fixed pattern, as buffers).
- :mod:`.pattern_correction`: :class:`PatternCorrection` (a pattern's corrections in order).
- :mod:`.complex_pattern`: :class:`ComplexPatternCorrection` (a calibrated complex-domain pattern).
- :mod:`.temporal`: :func:`temporal_filter`, :class:`TemporalFilter` (recordings: a causal
  recursive filter with a motion guard, its state passed in and out).
- :mod:`.temporal_sequence`: :class:`TemporalSequence` (the temporal filter over one recording's
  frames, the batch as time: the stage contract's form).
- :mod:`.stage`: the stage contract (:class:`~.stage.Stage`, :class:`~.stage.Setting`): how every
  stage here is written.
- :mod:`.flying`: :func:`flying_pixels`, :class:`FlyingPixels` (mixed pixels at depth edges: flags,
  a confidence map, invalidate or reassign).
"""

from .complex_pattern import ComplexPatternCorrection
from .destripe import Destripe, destripe
from .fixed_pattern import FixedPatternCorrection
from .flying import FlyingPixels, flying_pixels
from .fpn_filter import FPNFilter, fpn_filter
from .fusion import AmplitudeFusion, amplitude_fusion, amplitude_weight
from .pattern_correction import PatternCorrection
from .suppression import FPNSuppression
from .temporal import TemporalFilter, promised_noise_factor, temporal_filter, temporal_state
from .temporal_sequence import TemporalSequence
from .trainable import KeepZeros, TrainableFusion, freeze, keep_zeros
from .validity import all_valid, valid_mask

__all__ = [
    "AmplitudeFusion",
    "ComplexPatternCorrection",
    "Destripe",
    "FPNFilter",
    "FPNSuppression",
    "FixedPatternCorrection",
    "PatternCorrection",
    "TemporalFilter",
    "TemporalSequence",
    "FlyingPixels",
    "all_valid",
    "amplitude_fusion",
    "amplitude_weight",
    "destripe",
    "flying_pixels",
    "fpn_filter",
    "promised_noise_factor",
    "temporal_filter",
    "temporal_state",
    "valid_mask",
    "KeepZeros",
    "TrainableFusion",
    "freeze",
    "keep_zeros",
]
