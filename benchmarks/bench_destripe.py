"""Broadband destriping (tof_fpn_torch.runtime.destripe): every must-show number, printed and as JSON.

    python benchmarks/bench_destripe.py                       # all sections, writes the JSON and figure
    python benchmarks/bench_destripe.py --only adi            # adi | sim | sim-calibrated | speed |
                                                           # never-hurts
    python benchmarks/bench_destripe.py --json out.json --figure docs/figures/destripe_adi.png

Sections (definitions in docs/destripe.md):

* ``adi``: the real ADI ADTF3175 wall (tests/data/real). Column-stripe energy
  (tof_fpn_torch.analysis.stripe_energy: covariance of the top- and bottom-half column profiles of
  the 9-column horizontal high-pass, in a region away from the cable edge and the clutter) before,
  after destripe() of the whole frame, after destripe() of each half alone (the unbiased
  protocol), and after the notch filter; the low-pass (15 x 15) change of the depth over all valid
  pixels and over the cable-edge band. Writes the before/after figure.
* ``sim``: the raw simulator with broadband read-out FPN (ReadoutFPN periodic amplitudes 0,
  random_offset, random_gain), planar and synthetic scenes, three illumination levels; PSNR (eq. 9,
  D_MAX 7.5 m) of no correction, the notch stage (suppression_from_design()), destripe in the depth
  domain and in the complex domain, the FPN-free simulation and the oracle (true offsets removed).
* ``sim-calibrated``: the ``sim`` cases (same simulator, scenes, levels, seeds and held-out frame),
  corrected by a complex fixed pattern (tof_fpn_torch.analysis.calibrate_complex_pattern ->
  ComplexPatternCorrection) calibrated on T = 16 other frames: of the same scene with fresh noise,
  and separately of 16 different scenes of the same kind; beside no correction, notch, the
  single-frame depth and complex domains, FPN-free and the oracle. Also: the pattern calibrated on
  FPN-free frames applied to the FPN-free held-out frame (a camera without the pattern).
* ``speed``: destripe() on 32 x 424 x 512 float32 depth-like frames against the 42-tap notch filter
  (``filter_from_design(41, 0.12)`` uncompensated, as benchmarks/bench_fpn_filter.py), 2 threads,
  alternating calls: the median of the per-round ratios and the ratio of the minima (the machine's
  1-minute load average is recorded: other processes slow the many-op destripe far more than the
  single-convolution notch).
* ``never-hurts``: stripe-free noisy scenes (synthetic_scene, planar_scene, add_depth_noise), sizes
  32..640 odd and even: the change of PSNR and of the mean depth.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch
from real_captures import REAL_DATA_DIR

from tof_fpn_torch import constants as K
from tof_fpn_torch.analysis.calibrate_complex import calibrate_complex_pattern
from tof_fpn_torch.analysis.metrics import psnr
from tof_fpn_torch.analysis.stripe_energy import (
    column_stripe_energy,
    lowpass_change,
    structure_mask,
)
from tof_fpn_torch.build import filter_from_design, suppression_from_design
from tof_fpn_torch.runtime.destripe import destripe
from tof_fpn_torch.sim import (
    Camera,
    ReadoutFPN,
    Simulation,
    add_depth_noise,
    default_terms,
    planar_scene,
    synthetic_scene,
)

ROOT = Path(__file__).resolve().parents[1]


def _rel(path: Path) -> str:
    """``path`` relative to the checkout when inside it (the JSON is committed)."""
    path = Path(path).resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


REAL = REAL_DATA_DIR / "adi_adtf3175"
#: ADI wall region: rows above the clutter, columns away from the borders, split between halves
ADI_ROWS, ADI_BORDER, ADI_SPLIT = 416, 8, 208
#: ADI wall: |9-column high-pass| above this (mm), dilated by 6 px, is the cable edge
ADI_EDGE_MM = 4.0


def db(before: float, after: float) -> float | None:
    """``10 log10(before / after)``; None when ``after <= 0`` (no common pattern left)."""
    return 10.0 * math.log10(before / after) if after > 0 and before > 0 else None


def load_adi() -> tuple[torch.Tensor, torch.Tensor]:
    def read(name):
        raw = np.fromfile(REAL / name, dtype="<u2").reshape(512, 512).astype(np.float64)
        return torch.from_numpy(raw)[None, None]

    return read("wall_depth_u16le_512x512.bin"), read("wall_ir_u16le_512x512.bin")


def adi_region(depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(region for the stripe energy, cable-edge band) on the input frame."""
    quiet = structure_mask(depth, ADI_EDGE_MM, width=15, dilate=6)
    region = quiet.clone()
    region[..., ADI_ROWS:, :] = False
    region[..., :ADI_BORDER] = False
    region[..., -ADI_BORDER:] = False
    band = (depth > 0) & ~quiet
    band[..., ADI_ROWS:, :] = False
    return region, band


def section_adi(figure: Path | None) -> dict:
    depth, ir = load_adi()
    region, band = adi_region(depth)

    def energy(d):
        e = column_stripe_energy(d, region, width=9, split=ADI_SPLIT)
        return {
            "covariance_mm2": float(e.covariance[0]),
            "correlation": float(e.correlation[0]),
            "profile_spread_mm": float(e.spread[0]),
        }, e

    out = destripe(depth)
    halves = torch.cat(
        [destripe(depth[..., :ADI_SPLIT, :]), destripe(depth[..., ADI_SPLIT:, :])], 2
    )
    notch = filter_from_design()(depth)
    e0, r0 = energy(depth)
    res = {"region_pixels": int(region.sum()), "columns": int(r0.columns[0]), "before": e0}
    for name, d in (("whole_frame", out), ("halves_separately", halves), ("notch_only", notch)):
        e, _ = energy(d)
        e["reduction_db"] = db(e0["covariance_mm2"], e["covariance_mm2"])
        res[name] = e
    res["lowpass_change_rms_mm"] = {
        "all_valid": float(lowpass_change(depth, out, 15)[0]),
        "cable_edge_band": float(lowpass_change(depth, out, 15, band)[0]),
    }
    v = depth > 0
    res["change_rms_mm"] = float(((out - depth)[v]).pow(2).mean().sqrt())
    res["invalid_pixels_unchanged"] = bool(torch.equal(out[~v], depth[~v]))
    if figure is not None:
        _figure(depth, out, region, figure)
        res["figure"] = _rel(figure)
    return res


def _figure(depth, out, region, path: Path) -> None:
    from tof_fpn_torch.analysis.stripe_energy import row_highpass
    from tof_fpn_torch.plotting import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(2, 3, figsize=(10.5, 6.5))
    for row, (name, d) in enumerate((("input", depth), ("destripe", out))):
        hp = row_highpass(d, 9)[0, 0].numpy()
        ax[row, 0].imshow(d[0, 0].numpy(), cmap="viridis", vmin=280, vmax=460)
        ax[row, 0].set_title(f"{name}: depth (mm)")
        ax[row, 1].imshow(hp, cmap="gray", vmin=-3, vmax=3)
        ax[row, 1].set_title(f"{name}: 9-column high-pass (+-3 mm)")
        e = column_stripe_energy(d, region, width=9, split=ADI_SPLIT)
        ax[row, 2].plot(e.top[0].numpy(), lw=0.7, label="top half")
        ax[row, 2].plot(e.bottom[0].numpy(), lw=0.7, label="bottom half")
        ax[row, 2].set_ylim(-1.5, 1.5)
        ax[row, 2].set_title(
            f"{name}: column profiles, cov {float(e.covariance[0]):.4f} mm$^2$, "
            f"r {float(e.correlation[0]):.2f}",
            fontsize=9,
        )
        ax[row, 2].legend(fontsize=7, loc="upper right")
    for a in ax[:, :2].ravel():
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=40)
    plt.close(fig)


def _fpn_term(offset: float, gain: float) -> ReadoutFPN:
    return ReadoutFPN(
        offset_amplitudes=(0.0, 0.0),
        gain_amplitudes=(0.0, 0.0),
        random_offset=offset,
        random_gain=gain,
    )


def _oracle(depth, amp, fpn: ReadoutFPN, camera: Camera) -> torch.Tensor:
    """The simulator's own column offsets of ``z`` removed (offset part; gains left)."""
    n = camera.n_phases
    off, _ = fpn.patterns(n, depth.shape[-1], depth.device, torch.float64)
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    cr = (2.0 / n) * (off * torch.cos(th)[:, None]).sum(0) / camera.conversion_gain
    ci = -(2.0 / n) * (off * torch.sin(th)[:, None]).sum(0) / camera.conversion_gain
    scale = K.SPEED_OF_LIGHT_AIR / (4 * math.pi * camera.modulation_frequency)
    d, a = depth.double(), amp.double()
    zr, zi = a * torch.cos(d / scale), a * torch.sin(d / scale)
    nr, ni = zr - cr, zi - ci
    dphi = torch.atan2(ni * zr - nr * zi, nr * zr + ni * zi)
    y = torch.remainder(d + scale * dphi, 2 * math.pi * scale)
    return torch.where(d > 0, y, d).to(depth.dtype)


def section_sim(seeds=(0, 1, 2), levels=(0.03, 0.1, 0.3, 1.0), offset=100.0, gain=0.002) -> dict:
    notch = suppression_from_design()
    f = K.CAMCUBE_MODULATION_FREQUENCY_HZ
    scenes = {
        "planar": lambda s: planar_scene(204, 204, seed=s),
        "synthetic": lambda s: synthetic_scene(204, 204, seed=s, depth_range=(1.0, 6.0)),
    }
    methods = ("none", "notch", "depth", "complex", "fpn_free", "oracle")
    out: dict = {
        "settings": {
            "camera": "Camera(integration_time=1e-3, illumination_power=P, ambient_irradiance=0.02)",
            "fpn": f"ReadoutFPN(periodic 0, random_offset={offset} e-, random_gain={gain})",
            "seeds": list(seeds),
            "levels_P_W": list(levels),
        }
    }
    for sname, make in scenes.items():
        for level in levels:
            cam = Camera(integration_time=1e-3, illumination_power=level, ambient_irradiance=0.02)
            rows = {m: [] for m in methods}
            low_rows = {m: [] for m in methods}
            amps, sat = [], []
            free = {"none": [], "depth": [], "complex": []}
            free_psnr = {m: [] for m in free}
            for s in seeds:
                scene = make(s)
                fpn = _fpn_term(offset, gain)
                terms = default_terms()
                terms[2] = fpn
                res = Simulation(cam, terms).run(scene, seed=s)
                terms0 = default_terms()
                terms0[2] = _fpn_term(0.0, 0.0)
                clean = Simulation(cam, terms0).run(scene, seed=s)
                # saturated pixels carry no depth: reported invalid (0), as cameras do
                d = torch.where(res.saturated, 0.0, res.depth)
                a, gt = res.amplitude, scene.depth
                preds = {
                    "none": d,
                    "notch": notch(d, a),
                    "depth": destripe(d, a),
                    "complex": destripe(d, a, domain="complex", modulation_frequency_hz=f),
                    "fpn_free": torch.where(res.saturated, 0.0, clean.depth),
                    "oracle": _oracle(d, a, fpn, cam),
                }
                # never hurts, raw simulator: the FPN-free frame through both domains
                d0 = torch.where(res.saturated, 0.0, clean.depth)
                a0 = clean.amplitude
                free["depth"].append(destripe(d0, a0))
                free["complex"].append(
                    destripe(d0, a0, domain="complex", modulation_frequency_hz=f)
                )
                free["none"].append(d0)
                ok = ~res.saturated  # saturated pixels carry no depth (the camera flags them)
                low = ok & (a < K.LOW_SENSING_THRESHOLD)
                amps.append(float(a.median()))
                sat.append(float(res.saturated.double().mean()))
                for m, p in preds.items():
                    rows[m].append(float(psnr(p, gt, mask=ok)[0]))
                    low_rows[m].append(float(psnr(p, gt, mask=low)[0]))
                for m, p in free.items():
                    free_psnr[m].append(float(psnr(p[-1], gt, mask=ok)[0]))
            key = f"{sname}/P={level:g}"
            mean = {m: statistics.mean(v) for m, v in rows.items()}
            out[key] = {
                "median_amplitude": statistics.mean(amps),
                "saturated_share": statistics.mean(sat),
                "psnr_db": mean,
                "psnr_low_sensing_db": {m: statistics.mean(v) for m, v in low_rows.items()},
                "gain_over_none_db": {m: mean[m] - mean["none"] for m in methods},
                "fpn_free_change_db": {
                    m: [a - b for a, b in zip(free_psnr[m], free_psnr["none"], strict=True)]
                    for m in ("depth", "complex")
                },
            }
    return out


#: sim-calibrated: frames per calibration, and the seeds of its simulations / scenes (held-out: s)
CAL_FRAMES, CAL_SEED_SAME, CAL_SEED_DIFF, CAL_SCENE_SEED = 16, 1000, 2000, 100


def _sim_scenes(size: int = 204) -> dict:
    """The ``sim`` scenes: ``make(seed, batch)``."""
    return {
        "planar": lambda s, b=1: planar_scene(size, size, seed=s, batch=b),
        "synthetic": lambda s, b=1: synthetic_scene(
            size, size, seed=s, batch=b, depth_range=(1.0, 6.0)
        ),
    }


def _simulate(cam: Camera, scene, seed: int, frames: int = 1, offset=100.0, gain=0.002, raw=False):
    """Depth (saturated pixels 0, as cameras report them, unless ``raw``), amplitude and the
    saturation mask."""
    terms = default_terms()
    terms[2] = _fpn_term(offset, gain)
    res = Simulation(cam, terms).run(scene, frames=frames, seed=seed)
    d = res.depth if raw else torch.where(res.saturated, 0.0, res.depth)
    return d, res.amplitude, res.saturated


def calibrated_case(sname: str, level: float, seed: int, frames: int = CAL_FRAMES, size=204):
    """One ``sim-calibrated`` case: ``{method: PSNR gain over no correction (dB)}`` on the held-out
    frame (the ``sim`` section's), plus the calibrations' shrink factors, the patterns' errors
    against the simulator's complex offsets and the FPN-free change."""
    f = K.CAMCUBE_MODULATION_FREQUENCY_HZ
    make = _sim_scenes(size)[sname]
    cam = Camera(integration_time=1e-3, illumination_power=level, ambient_irradiance=0.02)
    fpn = _fpn_term(100.0, 0.002)
    scene = make(seed)
    d, a, sat = _simulate(cam, scene, seed)
    d0, a0, sat0 = _simulate(cam, scene, seed, offset=0.0, gain=0.0, raw=True)
    ok, gt = ~sat, scene.depth
    same = _simulate(cam, scene, CAL_SEED_SAME + seed, frames)
    many = make(CAL_SCENE_SEED + frames * seed, frames)
    diff = _simulate(cam, many, CAL_SEED_DIFF + seed)
    free = _simulate(cam, many, CAL_SEED_DIFF + seed, offset=0.0, gain=0.0)
    truth = _true_offsets(fpn, cam, size)
    out: dict = {"shrink_factor": {}, "pattern_error": {}}
    preds = {
        "none": d,
        "notch": suppression_from_design()(d, a),  # as in ``sim``: the default stage, gated
        "notch_ungated": suppression_from_design(gate=False)(d, a),  # notch + eq. 11 fusion
        "depth": destripe(d, a),
        "complex": destripe(d, a, domain="complex", modulation_frequency_hz=f),
        "fpn_free": torch.where(sat, 0.0, d0),
        "oracle": _oracle(d, a, fpn, cam),
    }
    for name, (cd, ca, _) in (("calibrated_same", same), ("calibrated_diff", diff)):
        pat = calibrate_complex_pattern(cd, ca, f)
        preds[name] = pat.module()(d, a)
        est = torch.stack([pat.column_offset_re, pat.column_offset_im])
        out["shrink_factor"][name] = pat.shrink_factor
        out["pattern_error"][name] = float(((est - truth) ** 2).sum() / (truth**2).sum())
    base = float(psnr(d, gt, mask=ok)[0])
    out["psnr_none_db"] = base
    out["gain_db"] = {m: float(psnr(p, gt, mask=ok)[0]) - base for m, p in preds.items()}
    # a camera without the pattern: calibrated on FPN-free frames, applied to the FPN-free frame
    pat0 = calibrate_complex_pattern(free[0], free[1], f)
    clean = torch.where(sat0, 0.0, d0)
    out["fpn_free_change_db"] = float(psnr(pat0.module()(clean, a0), gt, mask=~sat0)[0]) - float(
        psnr(clean, gt, mask=~sat0)[0]
    )
    return out


def _true_offsets(fpn: ReadoutFPN, camera: Camera, width: int) -> torch.Tensor:
    """(2, W) the simulator's complex column offsets (DN), zero mean (what can be identified)."""
    n = camera.n_phases
    off, _ = fpn.patterns(n, width, torch.device("cpu"), torch.float64)
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    c = torch.stack([(off * torch.cos(th)[:, None]).sum(0), -(off * torch.sin(th)[:, None]).sum(0)])
    c = (2.0 / n) * c / camera.conversion_gain
    return c - c.mean(-1, keepdim=True)


def section_sim_calibrated(seeds=(0, 1, 2), levels=(0.03, 0.1, 0.3, 1.0)) -> dict:
    out: dict = {
        "settings": {
            "as": "sim (same camera, FPN, scenes, levels, seeds; held-out frame = the sim frame)",
            "frames": CAL_FRAMES,
            "same_scene": f"scene seed s, simulation seed {CAL_SEED_SAME} + s, {CAL_FRAMES} frames",
            "different_scenes": f"scene seeds {CAL_SCENE_SEED} + {CAL_FRAMES} s + (0..15), "
            f"simulation seed {CAL_SEED_DIFF} + s",
            "calibration": "calibrate_complex_pattern(depth, amplitude, f) defaults",
        }
    }
    for sname in ("planar", "synthetic"):
        for level in levels:
            cases = [calibrated_case(sname, level, s) for s in seeds]
            mean = statistics.mean
            out[f"{sname}/P={level:g}"] = {
                "psnr_none_db": mean(c["psnr_none_db"] for c in cases),
                "gain_over_none_db": {
                    m: mean(c["gain_db"][m] for c in cases) for m in cases[0]["gain_db"]
                },
                "gain_per_seed_db": [c["gain_db"] for c in cases],
                "shrink_factor": [c["shrink_factor"] for c in cases],
                "pattern_error": [c["pattern_error"] for c in cases],
                "fpn_free_change_db": [c["fpn_free_change_db"] for c in cases],
            }
    return out


CAL_COLUMNS = (
    ("notch", "notch (gated)"),
    ("notch_ungated", "notch + fusion"),
    ("depth", "depth domain"),
    ("complex", "complex domain"),
    ("calibrated_same", "calibrated, same scene"),
    ("calibrated_diff", "calibrated, 16 scenes"),
    ("fpn_free", "FPN-free"),
    ("oracle", "oracle"),
)


def calibrated_table(res: dict) -> str:
    """The ``sim-calibrated`` result as the markdown table of docs/destripe.md."""
    head = "| scene, P | PSNR none | " + " | ".join(t for _, t in CAL_COLUMNS) + " |"
    lines = [head, "|" + "---|" * (len(CAL_COLUMNS) + 2)]
    for key, r in res.items():
        if "/P=" not in key:
            continue
        sname, level = key.split("/P=")
        g = r["gain_over_none_db"]
        cells = [f"{g[m]:+.2f}" for m, _ in CAL_COLUMNS]
        lines.append(f"| {sname}, {level} | {r['psnr_none_db']:.2f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _load() -> float | None:
    try:
        return os.getloadavg()[0]
    except OSError:
        return None


def _alternate(calls: dict, rounds: int) -> dict:
    """Call each function once per round, in the same order; times in seconds."""
    times = {k: [] for k in calls}
    with torch.inference_mode():
        for fn in calls.values():
            fn()
        for _ in range(rounds):
            for k, fn in calls.items():
                t = time.perf_counter()
                fn()
                times[k].append(time.perf_counter() - t)
    return times


def section_speed(rounds=31, threads=2) -> dict:
    """Headline: the notch and destripe alternating, nothing else in the loop (a bigger call in
    the same loop frees and re-faults memory the next call then pays for). Then each variant
    against the notch in its own loop."""
    torch.set_num_threads(threads)
    gen = torch.Generator().manual_seed(0)
    # depth-like frames (as benchmarks/bench_fpn_filter.py): a slanted curved surface, 1 cm noise and
    # 5 mm column offsets. (Uniform random values ring below 0 through the notch, which then
    # keeps those inputs on a slower masked path: that made the notch 3x slower than it is.)
    shape = (32, 1, 424, 512)
    yy = torch.linspace(0.0, 1.0, 424).view(1, 1, -1, 1)
    xx = torch.linspace(0.0, 1.0, 512).view(1, 1, 1, -1)
    phase = 6.0 * torch.rand(32, 1, 1, 1, generator=gen)
    x = 2.0 + 0.8 * yy + 0.3 * torch.sin(5.0 * xx + phase)
    x = x + 0.005 * torch.randn(1, 1, 1, 512, generator=gen)
    x = (x + 0.01 * torch.randn(shape, generator=gen)).contiguous()
    amp = 50.0 + 250.0 * torch.rand(shape, generator=gen)
    # the 42-tap filter of benchmarks/bench_fpn_filter.py (order 41, uncompensated)
    f = filter_from_design(41, 0.12, compensate_delay=False, allow_shift=True)
    variants = {
        "destripe": lambda: destripe(x),
        "destripe_rows_and_columns": lambda: destripe(x, dim=(-2, -1)),
        "destripe_complex": lambda: destripe(
            x, amp, domain="complex", modulation_frequency_hz=K.CAMCUBE_MODULATION_FREQUENCY_HZ
        ),
    }
    res = {"shape": [32, 1, 424, 512], "threads": threads, "rounds": rounds, "load_average": []}
    for name, fn in variants.items():
        res["load_average"].append(_load())
        times = _alternate({"notch": lambda: f(x), name: fn}, rounds)
        base, v = times["notch"], times[name]
        res[name] = {
            "median_ms": 1e3 * statistics.median(v),
            "min_ms": 1e3 * min(v),
            "notch_median_ms": 1e3 * statistics.median(base),
            "notch_min_ms": 1e3 * min(base),
            "ratio_to_notch_median": statistics.median(a / b for a, b in zip(v, base, strict=True)),
            "ratio_of_minima": min(v) / min(base),
        }
    res["load_average"].append(_load())
    return res


def section_never_hurts(sizes=(32, 33, 64, 65, 101, 128, 204, 255, 256, 511, 512, 640)) -> dict:
    rows = []
    for size in sizes:
        for sname, make in (("synthetic", synthetic_scene), ("planar", planar_scene)):
            scene = make(size, size, seed=size)
            for lam in (1.0, 100.0):
                g = torch.Generator().manual_seed(size)
                noisy = add_depth_noise(
                    scene.depth, scene.amplitude, lam, amplitude_floor=10.0, generator=g
                )
                for dim in (-1, (-2, -1)):
                    out = destripe(noisy, dim=dim)
                    p0, p1 = float(psnr(noisy, scene.depth)[0]), float(psnr(out, scene.depth)[0])
                    m0, m1 = noisy.double().mean(), out.double().mean()
                    rows.append(
                        {
                            "size": size,
                            "scene": sname,
                            "lambda": lam,
                            "dim": str(dim),
                            "psnr_in_db": p0,
                            "psnr_change_db": p1 - p0,
                            "mean_change_percent": float(100 * (m1 - m0) / m0),
                        }
                    )
    return {
        "cases": rows,
        "max_abs_psnr_change_db": max(abs(r["psnr_change_db"]) for r in rows),
        "max_abs_mean_change_percent": max(abs(r["mean_change_percent"]) for r in rows),
    }


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument(
        "--only", choices=("adi", "sim", "sim-calibrated", "speed", "never-hurts"), action="append"
    )
    p.add_argument("--json", type=Path, default=ROOT / "docs" / "figures" / "destripe_bench.json")
    p.add_argument("--figure", type=Path, default=ROOT / "docs" / "figures" / "destripe_adi.png")
    p.add_argument("--rounds", type=int, default=31, help="speed rounds")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    sections = args.only or ["adi", "sim", "sim-calibrated", "speed", "never-hurts"]
    torch.set_num_threads(args.threads)
    cmd = sys.argv[1:] if argv is None else argv
    results: dict = {"command": " ".join(["python benchmarks/bench_destripe.py", *cmd])}
    for name in sections:
        t = time.perf_counter()
        if name == "adi":
            results[name] = section_adi(args.figure)
        elif name == "sim":
            results[name] = section_sim()
        elif name == "sim-calibrated":
            results[name] = section_sim_calibrated()
        elif name == "speed":
            results[name] = section_speed(args.rounds, args.threads)
        else:
            results[name] = section_never_hurts()
        results[name]["seconds"] = time.perf_counter() - t
        print(f"== {name}")
        if name == "sim-calibrated":
            print(calibrated_table(results[name]))
            continue
        shown = dict(results[name])
        shown.pop("cases", None)
        print(json.dumps(shown, indent=1, default=float))
    if args.json:
        # sections not run this time keep their last results; each section names its command
        old = json.loads(args.json.read_text()) if args.json.exists() else {}
        for section in old.values():
            if isinstance(section, dict) and "command" not in section:
                section["command"] = old.get("command")
        for name in sections:
            results[name]["command"] = results["command"]
        results = {**old, **results}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=1, default=float) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
