"""Camera profiles: each camera's units and the amplitude gating of eq. (11) in those units.

The paper's fusion thresholds (70 and 350) are CamCube amplitude units. Other cameras report
amplitude (active brightness, IR) on other scales, so the same numbers gate them arbitrarily. The
unit-free quantity that transfers is the *relative depth noise* ``sigma_D(A) / D = k / (A D)``
(eq. 2, ``sigma_D = k / A``): on the paper's own synthetic data (Table I's eq. 2 noise, 21.26 dB;
measured ``k`` = 13.5 m x amplitude over seeds 0-2, median depth 4.85 m) the paper's 70 and 350
are where the relative noise is 4 % and 0.8 %
(:data:`~tof_fpn_torch.constants.FUSION_LOW_RELATIVE_NOISE`, ``FUSION_HIGH_RELATIVE_NOISE``).
:func:`tof_fpn_torch.build.fusion_from_data` measures ``k`` on a capture and places the thresholds
there, in that capture's units. A profile records the result for a camera, or ``None`` where no
public capture with amplitude exists to measure it on (then use ``fusion_from_data``).
"""

from __future__ import annotations

from dataclasses import dataclass

from . import constants as K

__all__ = ["PROFILES", "CameraProfile", "profile"]


@dataclass(frozen=True)
class CameraProfile:
    """Units and amplitude gating of one camera.

    Attributes:
        name: the key in :data:`PROFILES`.
        amplitude_unit: what the camera's amplitude channel is and its scale.
        depth_unit: the unit of its depth frames.
        modulation_frequencies_hz: its modulation frequencies.
        fusion_low, fusion_high: eq. (11) thresholds in ``amplitude_unit`` (None: not known).
        source: where the numbers come from.
    """

    name: str
    amplitude_unit: str
    depth_unit: str
    modulation_frequencies_hz: tuple[float, ...]
    fusion_low: float | None
    fusion_high: float | None
    source: str


PROFILES: dict[str, CameraProfile] = {
    "camcube": CameraProfile(
        "camcube",
        "PMD CamCube 2.0 amplitude (the paper's units; low sensing below 300)",
        "m",
        (K.CAMCUBE_MODULATION_FREQUENCY_HZ,),
        K.FUSION_LOW,
        K.FUSION_HIGH,
        "Georgiev et al., IEEE SAS 2015, Sec. IV (70 / 350)",
    ),
    "adtf3175": CameraProfile(
        "adtf3175",
        "Analog Devices ADTF3175 active brightness (AB), 12-bit counts",
        "mm",
        (),
        16.0,
        80.0,
        "fusion_from_data on the public wall capture (analogdevicesinc/ToF, out_depth_/out_ir_): "
        "k = 221 mm x AB, median depth 347 mm; `python benchmarks/camera_profiles.py`. The "
        "office capture (another mode) gives 5x lower k: thresholds depend on the mode",
    ),
    "kinect_v2": CameraProfile(
        "kinect_v2",
        "Microsoft Kinect v2 IR amplitude, 16-bit",
        "mm",
        (80e6, 16e6, 120e6),
        None,
        None,
        "no public capture with amplitude here (only the P0 tables): use fusion_from_data",
    ),
    "azure_kinect": CameraProfile(
        "azure_kinect",
        "Azure Kinect DK active IR, 16-bit (NFOV unbinned 640 x 576)",
        "mm",
        (),
        2.7,
        13.5,
        "fusion_from_data on the public pyk4a recording (tests/assets/recording.mkv, read with "
        "tof_fpn_torch.io.read_azure_kinect_mkv; saturated IR 65535 left out): k = 0.161 m x IR, "
        "median depth 1.49 m, one frame; `python benchmarks/camera_profiles.py`",
    ),
    "realsense": CameraProfile(
        "realsense",
        "Intel RealSense infrared image as recorded (Y8: 8-bit, Y16: 16-bit grey levels)",
        "depth units of the recording (1 mm unless the bag states others)",
        (),
        None,
        None,
        "no RealSense capture with infrared measured here: use fusion_from_data. D400 depth is "
        "active stereo and L515 depth is LiDAR, not continuous-wave ToF",
    ),
    "espros_tofcam635": CameraProfile(
        "espros_tofcam635",
        "ESPROS TOFcam635 (epc635, 160 x 60) amplitude as the epc-tofcam-toolkit records it "
        "(LSB; saturates near 2896)",
        "mm (the toolkit's point cloud x, y, z; read as z, the optical-axis depth)",
        (),
        None,
        None,
        "each recording states its modulation frequency (mod_frequency; the toolkit offers 10 "
        "and 20 MHz). No fusion thresholds measured here: use fusion_from_data",
    ),
}


def profile(name: str) -> CameraProfile:
    """The profile called ``name`` (case-insensitive); ``ValueError`` listing the known ones."""
    key = str(name).lower()
    if key not in PROFILES:
        raise ValueError(f"unknown camera profile {name!r}; known: {sorted(PROFILES)}")
    return PROFILES[key]
