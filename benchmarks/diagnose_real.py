"""``diagnose`` on real data: the ADI ADTF3175 wall capture, the Azure Kinect desk recording, the
ESPROS TOFcam635 point cloud and a Kinect v2 P0 pattern.

1. ADI wall (``tests/data/real/adi_adtf3175``): one frame, 512 x 512, depth and IR, no scene:
   the scene is estimated from the capture. Expected: ``fpn_pattern`` with a broadband column
   profile (not the 2 pi / 3 and pi of the baseline), fit improved.
2. Azure Kinect desk (``tests/data/real/azure_kinect/desk_recording.mkv``, as it is): its
   depth and active IR (one frame), no scene: the scene is estimated from the recording.
3. ESPROS TOFcam635 (``tests/data/real/espros_tofcam635``): the point cloud as the
   epc-tofcam-toolkit wrote it (14 frames, 60 x 160, 20 MHz); the diagnosis keeps the 8 frames
   of its main pose itself (the other poses are named in a note) and estimates the scene from
   them. Beside it, the column pattern of the toolkit's amplitude recording of the same camera
   (85 frames): per frame the column means of the rows, less their 15-column running mean (the
   scene's slow change along the rows), averaged over the frames.
4. Kinect v2 P0 column structure: the column-to-column phase steps of the 80 MHz P0 table
   (median over rows; its rows alternate by pi, so steps along the row are used), high-passed
   over 31 columns, 160 central columns, converted to depth at 80 MHz, added to every frame of a
   recording that ``benchmarks/concealed_generator.py`` makes of a simulated scene (120 x 160, 24
   frames, scene given).

    python benchmarks/diagnose_real.py            # writes docs/figures/diagnosis_real.json
                                                  # and each case's residual figure
                                                  # docs/figures/diagnosis_real_<case>.png
    python benchmarks/diagnose_real.py NAME ...   # only those cases (the others kept from the JSON)

A missing capture is an error (the script stops and says where it looked).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
from concealed_generator import C_AIR, generate  # noqa: E402 (a sibling script)
from real_captures import REAL_DATA_DIR as REAL  # noqa: E402 (a sibling script)

AZURE = "azure_kinect/desk_recording.mkv"
ADI = ("adi_adtf3175/wall_depth_u16le_512x512.bin", "adi_adtf3175/wall_ir_u16le_512x512.bin")
P0 = "kinect_v2_p0/p0tables_3x424x512_u16le.dat"
ESPROS = (
    "espros_tofcam635/point_cloud_w544c005_250527_134722.h5",
    "espros_tofcam635/amplitude_w544c005_250527_134627.h5",
)


def _path(rel: str) -> Path:
    p = REAL / rel
    if not p.is_file():
        raise SystemExit(f"real capture missing: {p}")
    return p


def _figure(diag, name: str) -> None:
    """The diagnosis' residual figure (before / after along the located axes) into the docs."""
    files = diag.files(figures=True)
    (ROOT / "docs" / "figures" / f"diagnosis_real_{name}.png").write_bytes(
        files["residual_axes.png"]
    )


def _summary(diag) -> dict:
    rep = diag.report
    out = {
        "verdict": rep["verdict"],
        "effects": rep["effects"],
        "also_consistent_with": rep.get("also_consistent_with", []),
        "fit": rep["fit"],
        "located_before": [
            {k: w.get(k) for k in ("statistic", "axis", "excess_sigma", "spectrum") if k in w}
            for w in rep["located_before"]
        ],
        "unexplained": [w.get("statistic") for w in rep["unexplained"]],
        "notes": rep["recording"]["notes"],
        "seconds": rep["seconds"],
    }
    return out


def adi() -> dict:
    from tof_fpn_torch import io as tio
    from tof_fpn_torch.diagnosis import diagnose

    depth, ir = tio.read_adi_depth_ir(_path(ADI[0]), _path(ADI[1]))
    meta = {
        "modulation_frequency_hz": None,
        "integration_time_us": None,
        "n_phases": None,
        "amplitude_unit": "IR counts",
        "source": "ADI ADTF3175 wall capture (one frame)",
    }
    rec = tio.Recording(depth, ir, meta)
    diag = diagnose(rec, None)
    _figure(diag, "adi_wall")
    return _summary(diag)


def azure() -> dict:
    from tof_fpn_torch import io as tio
    from tof_fpn_torch.diagnosis import diagnose

    diag = diagnose(tio.read_azure_kinect_mkv(_path(AZURE)), None)
    _figure(diag, "azure_kinect_desk")
    return _summary(diag)


def column_pattern(frames: np.ndarray, window: int = 15) -> np.ndarray:
    """The column pattern (W,) of amplitude ``frames`` (T, H, W; NaN: left out): per frame the
    column means of the rows, less their ``window``-column running mean (edge-padded; over the
    columns that have a mean), averaged over the frames."""
    ok = np.isfinite(frames)
    n = ok.sum(1)
    cols = np.where(n > 0, np.where(ok, frames, 0.0).sum(1) / np.maximum(n, 1), np.nan)
    half = window // 2
    has = np.isfinite(cols)
    kernel = np.ones(window)

    def run(x: np.ndarray) -> np.ndarray:
        padded = np.pad(x, ((0, 0), (half, half)), mode="edge")
        return np.stack([np.convolve(c, kernel, "valid") for c in padded])

    smooth = run(np.where(has, cols, 0.0)) / np.maximum(run(has.astype(float)), 1e-12)
    return np.nanmean(cols - smooth, axis=0)


def _power_near(profile: np.ndarray) -> dict:
    """Shares of the profile's power (mean removed) at pi (even / odd columns) and near 2 pi / 3."""
    x = profile - profile.mean()
    spec = np.abs(np.fft.rfft(x)) ** 2
    freq = np.fft.rfftfreq(x.size) * 2 * math.pi
    total = float(spec[1:].sum())
    near = {
        "pi": float(spec[np.abs(freq - math.pi) < 0.05].sum()) / total,
        "2pi/3": float(spec[np.abs(freq - 2 * math.pi / 3) < 0.05].sum()) / total,
    }
    return {k: round(v, 4) for k, v in near.items()}


def espros() -> dict:
    import h5py

    from tof_fpn_torch import io as tio
    from tof_fpn_torch.diagnosis import diagnose

    cloud, amp_file = _path(ESPROS[0]), _path(ESPROS[1])
    diag = diagnose(cloud, None)  # the file as the toolkit wrote it: 14 frames, 6 poses
    _figure(diag, "espros_tofcam635")
    out = _summary(diag)
    out["frames_in_file"] = int(tio.read_espros_hdf5(cloud).depth.shape[0])
    out["frames_diagnosed"] = int(diag.obs.frames)
    with h5py.File(amp_file, "r") as f:
        frames = np.asarray(f["frames_0"][()], dtype=np.float64)
    at_top = frames == frames.max()  # the saturation code (below), left out
    prof = column_pattern(np.where(at_top, np.nan, frames))
    even_odd = float(prof[0::2].mean() - prof[1::2].mean())
    out["amplitude_recording"] = {
        "frames": int(frames.shape[0]),
        "median_amplitude": float(np.median(frames)),
        "share_at_the_top_value": float(at_top.mean()),
        "column_pattern_rms": float(prof.std()),
        "column_pattern_even_minus_odd": even_odd,
        "column_pattern_power_share_near": _power_near(prof),
    }
    # the same pattern in the point cloud's amplitude (its diagnosed frames)
    pc = diag.obs.amplitude.double().numpy()
    pc = np.where(pc == np.nanmax(pc), np.nan, pc)
    prof_pc = column_pattern(pc)
    out["amplitude_recording"]["correlation_with_point_cloud_amplitude_columns"] = float(
        np.corrcoef(prof, prof_pc)[0, 1]
    )
    # the toolkit writes a saturated pixel with the amplitude's top value and one fixed z (the
    # same for every such pixel): read as it is, a constant depth of zero spread; the diagnosis
    # again with those frame-pixels invalid
    rec = tio.read_espros_hdf5(cloud)
    amp = rec.amplitude.numpy()
    top = float(amp.max())
    flag = amp == amp.max()
    z_at_top = np.unique(rec.depth.numpy()[flag])
    out["saturation_flag"] = {
        "amplitude": top,
        "share_of_frame_pixels": float(flag.mean()),
        "distinct_depths_at_it": int(z_at_top.size),
        "depth_mm_at_it": float(z_at_top[0] * 1e3),
    }
    depth = np.where(flag, np.nan, rec.depth.numpy())
    masked = tio.Recording(
        torch.from_numpy(depth), rec.amplitude, rec.meta, timestamps_s=rec.timestamps_s
    )
    diag_m = diagnose(masked, None)
    _figure(diag_m, "espros_tofcam635_flags_invalid")
    out["saturation_flag"]["diagnosis_with_the_flagged_pixels_invalid"] = _summary(diag_m)
    return out


#: modulation frequencies of the three P0 tables (libfreenect2's order)
P0_FREQUENCIES = (80e6, 16e6, 120e6)


def p0_column_profile(width: int = 160, table: int = 0) -> np.ndarray:
    """The P0 table's column structure in metres (``width`` central columns) at its frequency."""
    from tof_fpn_torch import io as tio

    t = tio.read_kinect_v2_p0(_path(P0))[table, 0].double().numpy()  # rad
    z = np.exp(1j * t)
    step = np.median(np.angle(z[:, 1:] * np.conj(z[:, :-1])), axis=0)
    col = np.concatenate([[0.0], np.cumsum(step)])
    hp = col - np.convolve(np.pad(col, 15, mode="edge"), np.ones(31) / 31, "valid")
    c0 = (hp.size - width) // 2
    prof = hp[c0 : c0 + width] * C_AIR / (4 * math.pi * P0_FREQUENCIES[table])
    return prof - prof.mean()


def kinect(seed: int = 3, table: int = 0) -> dict:
    from tof_fpn_torch.diagnosis import diagnose
    from tof_fpn_torch.io import Recording
    from tof_fpn_torch.sim import synthetic_scene

    h, w, t = 120, 160, 24
    sc = synthetic_scene(h, w, seed=seed, depth_range=(0.5, 6.0))
    d = sc.depth[0, 0].double().numpy()
    r = sc.reflectance[0, 0].double().numpy()
    depth, amp, meta, _ = generate(d, r, frames=t, seed=seed)
    prof = p0_column_profile(w, table)
    depth = depth + prof[None, None, :].astype(np.float32)
    rec = Recording(torch.from_numpy(depth), torch.from_numpy(amp), meta)
    diag = diagnose(rec, sc)
    _figure(diag, f"kinect_v2_p0_{P0_FREQUENCIES[table] / 1e6:.0f}mhz")
    out = _summary(diag)
    out["p0_table_mhz"] = P0_FREQUENCIES[table] / 1e6
    out["planted_profile_rms_mm"] = float(prof.std() * 1e3)
    out["planted_profile_peak_to_peak_mm"] = float(np.ptp(prof) * 1e3)
    fitted = diag.model.profiles.get("columns")
    if fitted is not None:
        f = fitted.double().numpy()
        if f.std() > 0:
            out["profile_correlation"] = float(np.corrcoef(f - f.mean(), prof)[0, 1])
    return out


def _run(job: tuple) -> tuple:
    torch.set_num_threads(1)
    name, fn, args = job
    t0 = time.perf_counter()
    out = fn(*args)
    out["wall_seconds"] = time.perf_counter() - t0
    return name, out


def main() -> None:
    from concurrent.futures import ProcessPoolExecutor

    res = {}
    only = sys.argv[1:]
    jobs = [
        ("adi_wall", adi, ()),
        ("azure_kinect_desk", azure, ()),
        ("espros_tofcam635", espros, ()),
        ("kinect_v2_p0_columns_80mhz", kinect, (3, 0)),
        ("kinect_v2_p0_columns_16mhz", kinect, (3, 1)),
    ]
    out = ROOT / "docs" / "figures" / "diagnosis_real.json"
    if only and out.is_file():
        res = json.loads(out.read_text())
    jobs = [j for j in jobs if not only or j[0] in only]
    with ProcessPoolExecutor(2) as pool:  # the two slow single frames first, side by side
        for name, r in pool.map(_run, jobs):
            res[name] = r
            print(name, json.dumps(r["verdict"]), json.dumps(r["fit"]), flush=True)
    out.write_text(json.dumps(res, indent=1, default=float) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
