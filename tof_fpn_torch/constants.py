"""The paper's numbers and the defaults shared across layers, each written once (standard library
only).

Georgiev, Bregovic, Gotchev, "Fixed-pattern noise suppression in low-sensing environment of
Time-of-Flight devices", IEEE SAS 2015 (DOI 10.1109/SAS.2015.7133633). Every module reads these
names; ``tests/test_layout.py`` fails if one of the paper's values is written as a literal anywhere
else in the package. A setting that one module uses lives beside its code, as a documented
module-level default (e.g. ``FALSE_ALARM`` of :mod:`tof_fpn_torch.runtime.gate`). TorchScript reads
these as module attributes (``constants.D_MAX``), which it folds into constants; it cannot read
bare module-level globals (run-time modules pass their own settings as parameter defaults).
"""

from __future__ import annotations

import math

# --- camera (PMD CamCube 2.0, Sec. I and IV) ---------------------------------------------------
#: Modulation frequency of the paper's camera, Hz.
CAMCUBE_MODULATION_FREQUENCY_HZ: float = 20e6
#: Side of the CamCube 2.0 frame, pixels (204 x 204).
CAMCUBE_SIZE: int = 204
#: Speed of light in vacuum, m/s.
SPEED_OF_LIGHT: float = 299_792_458.0
#: Refractive index of dry air (the paper's ``c_L`` is the speed of light in air).
AIR_REFRACTIVE_INDEX: float = 1.000293
#: ``c_L``, m/s.
SPEED_OF_LIGHT_AIR: float = SPEED_OF_LIGHT / AIR_REFRACTIVE_INDEX

# --- metrics (eq. 9, Sec. II-A) ----------------------------------------------------------------
#: Peak depth of eq. (9), metres: the 20 MHz unambiguous range ``c_L / 2f = 7.49 m``, rounded.
D_MAX: float = 7.5
#: Amplitude below which a pixel is "low-sensing" (Sec. II-A, Table II's LOW), CamCube units.
LOW_SENSING_THRESHOLD: float = 300.0

# --- FPN frequencies and the default notch filter (Sec. III, Table I) --------------------------
#: Spatial frequencies of the CamCube fixed-pattern noise, radians per sample.
FPN_FREQUENCIES: tuple[float, float] = (2.0 * math.pi / 3.0, math.pi)
#: Default notches of the design: the FPN frequencies, ascending.
DEFAULT_NOTCHES: tuple[float, ...] = FPN_FREQUENCIES
#: Table I's best adaptive filter ``{order, rho}``: the package's default stage.
DEFAULT_ORDER: int = 20
DEFAULT_RHO: float = 0.14

# --- amplitude-gated fusion (eq. 11), CamCube amplitude units ----------------------------------
#: ``delta_A = 1`` up to this amplitude.
FUSION_LOW: float = 70.0
#: ``delta_A = FUSION_FLOOR`` from this amplitude on.
FUSION_HIGH: float = 350.0
#: Weight of the filtered depth for strong signals.
FUSION_FLOOR: float = 0.2
#: The same thresholds in a unit-free form for any camera (tof_fpn_torch.cameras): the relative
#: depth noise sigma_D(A) / D at which the fusion starts to ramp (4 %) and reaches its floor (0.8 %);
#: on the paper's synthetic data (Table I's noise) these are amplitudes 70 and 350.
FUSION_LOW_RELATIVE_NOISE: float = 0.04
FUSION_HIGH_RELATIVE_NOISE: float = 0.008

# --- the stripe gate of the FPN stage (runtime/gate.py; beyond the paper) -----------------------
#: Smallest stripe amplitude, in units of the per-pixel variation the notch sees besides stripes
#: (noise, scene detail), that opens the gate (fully at 2x): a stripe whose power is under 1 % of
#: that is not worth what a notch does to the scene. (The real ADI wall's 7 um row stripe at pi is
#: at ~0.03; the paper's synthetic FPN at ~0.3.)
GATE_MIN_STRIPE: float = 0.1

# --- stripe detection (analysis/stripes.py) ---------------------------------------------------
#: Largest false-alarm probability of a reported periodic stripe (whole searched band).
DETECTION_FALSE_ALARM: float = 0.01

# --- the temporal filter of recordings (runtime/temporal.py; beyond the paper) -----------------
#: EMA weight of the new frame once the average has settled (noise sd x 0.33 without restarts).
TEMPORAL_ALPHA: float = 0.2
#: Motion guard, standard deviations of the innovation: a pixel restarts beyond it (0.27 % of
#: static frames on Gaussian noise).
TEMPORAL_GUARD: float = 3.0
#: Depth noise standard deviation the guard assumes without a noise law, metres.
TEMPORAL_SIGMA: float = 0.005

# --- the depth-domain FPN model (eq. 10, reconstructed; Sec. IV-B) -----------------------------
FPN_ALPHA: float = -3.966
FPN_BETA: float = 0.012
FPN_GAMMA: float = 5.25

# --- robust noise estimation -------------------------------------------------------------------
#: Daubechies-2 decomposition high-pass filter (``pywt.Wavelet('db2').dec_hi``).
DB2_DEC_HI: tuple[float, float, float, float] = (
    -0.48296291314453416,
    0.8365163037378079,
    -0.2241438680420134,
    -0.12940952255126037,
)
#: ``1 / Phi^-1(3/4)``: median absolute value of N(0, 1) to its standard deviation.
MAD_TO_SIGMA: float = 1.482602218505602
#: In NLM's noise map ``k / A`` a valid pixel's amplitude counts as at least this fraction of its
#: image's median amplitude (``A = 0`` is valid but has no finite noise level).
NLM_AMPLITUDE_FLOOR: float = 0.01
#: ``log2(e)``: weights computed with ``exp2`` fold this factor into their argument.
LOG2_E: float = 1.4426950408889634

# --- the paper's reported results (Table I) and its filter family (Fig. 5, Fig. 9) -------------
#: Table I's filters, in the paper's row order.
TABLE1_FILTERS: tuple[tuple[int, float], ...] = (
    (20, 0.14),
    (28, 0.13),
    (40, 0.09),
    (17, 0.14),
    (31, 0.14),
    (41, 0.12),
)
#: Table I: case -> {(order, rho): (NLM not filtered, NLM filtered, NLM filtered + adaptive)} dB.
PAPER_TABLE1: dict[str, dict[tuple[int, float], tuple[float, float, float]]] = {
    "fpn": {
        (20, 0.14): (25.28, 30.20, 31.45),
        (28, 0.13): (25.28, 30.32, 31.33),
        (40, 0.09): (25.28, 30.04, 31.10),
        (17, 0.14): (25.28, 28.35, 30.44),
        (31, 0.14): (25.28, 28.29, 30.43),
        (41, 0.12): (25.28, 28.18, 30.26),
    },
    "fpn+noise": {
        (20, 0.14): (24.79, 29.51, 30.58),
        (28, 0.13): (24.79, 29.56, 30.48),
        (40, 0.09): (24.79, 29.28, 30.24),
        (17, 0.14): (24.79, 27.80, 29.62),
        (31, 0.14): (24.79, 27.74, 29.60),
        (41, 0.12): (24.79, 27.62, 29.48),
    },
}
#: Table I header: input PSNR (before NLM) of each case.
PAPER_INPUT_PSNR: dict[str, float] = {"fpn": 24.51, "fpn+noise": 21.26}
#: Fig. 5 / Fig. 9 filter family.
FIG9_ODD_ORDERS: tuple[int, ...] = (5, 9, 17, 21, 31, 41, 53)
FIG9_EVEN_ORDERS: tuple[int, ...] = (8, 12, 20, 28, 40, 52)
FIG9_RHOS: tuple[float, ...] = tuple(round(0.02 + 0.01 * i, 2) for i in range(15))  # 0.02..0.16

# --- broadband column / row destriping and fixed-pattern calibration (beyond the paper) --------
#: Width (columns) of the local-linear high-pass applied to the integrated offset profile of
#: :func:`~tof_fpn_torch.runtime.destripe` (at most a quarter of the line is used): offsets that
#: vary more slowly are left to the scene (the low-pass depth does not move).
DESTRIPE_WIDTH: int = 31
#: Differences between neighbouring columns further than this many robust sigmas from the pilot
#: are scene structure (edges, bars, clutter), not stripes: the pilot replaces them in the means.
DESTRIPE_CLIP: float = 3.0
#: A column step (mean difference between neighbouring columns) further than this many robust
#: sigmas (MAD) from the median step is a scene edge that most rows share, not a stripe: dropped
#: (unless too many are: ``MAX_EDGE_SHARE`` of runtime/_destripe_core.py).
DESTRIPE_STEP_CLIP: float = 5.0
#: Rows of the strided subsample (half in each half of the frame) on which the robust scale and
#: the pilot are computed.
DESTRIPE_PILOT_ROWS: int = 32
#: Window (columns) of ``shrink="local"``: the cross-validated factor is computed per window.
DESTRIPE_LOCAL_WIDTH: int = 128

# --- the simulator's multipath (sim/multipath.py; the diagnosis profiles around them) ------------
#: ``sim.Multipath``'s relay within the visible scene (``sim.relay``): default horizontal field of
#: view (deg) and near-field length (m), the step (px) between its source patches, raised so that
#: at most ``MULTIPATH_MAX_SOURCES`` are used (used by sim/multipath.py alone, but 300 is also the
#: paper's LOW_SENSING_THRESHOLD, which tests/test_layout.py flags anywhere else; the step goes
#: with it).
MULTIPATH_FIELD_OF_VIEW_DEG: float = 70.0
MULTIPATH_NEAR_FIELD_M: float = 1.0
MULTIPATH_RELAY_STEP: int = 8
MULTIPATH_MAX_SOURCES: int = 300

# --- Table II (real-case data) and its protocol (Sec. IV-A, IV-C) --------------------
#: Integration times of Table II's low-sensing captures, s.
TABLE2_INTEGRATION_TIMES: tuple[float, ...] = (50e-6, 100e-6, 200e-6)
#: Ground truth: the mean of this many frames at the normal-mode integration time below.
TABLE2_GT_FRAMES: int = 200
TABLE2_GT_INTEGRATION_TIME: float = 2000e-6
#: Table II's {LOW, IMP} in percent per integration time (same order as the times).
PAPER_TABLE2_SENSING: tuple[tuple[float, float], ...] = ((100.0, 11.0), (94.0, 5.0), (83.0, 2.0))
#: Table II: method -> (not filtered, filtered) PSNR in dB per integration time (same order).
PAPER_TABLE2: dict[str, tuple[tuple[float, float], ...]] = {
    "none": ((19.3, 21.3), (22.3, 24.3), (26.3, 27.6)),
    "nlm": ((22.1, 26.7), (27.3, 30.4), (32.8, 35.0)),
    "hypbi": ((20.8, 25.0), (23.6, 28.4), (28.7, 32.4)),
    "lpa-ici": ((24.6, 28.8), (28.9, 31.8), (33.8, 35.1)),
    "bm3d": ((24.3, 28.4), (28.8, 31.4), (32.9, 35.4)),
    "sdct": ((24.4, 26.4), (26.2, 27.9), (27.8, 28.1)),
}
