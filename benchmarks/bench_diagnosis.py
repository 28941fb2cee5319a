"""Concealed-effect benchmark of ``tof_fpn_torch.diagnosis``.

Recordings come from ``benchmarks/concealed_generator.py`` (NumPy, its own formulas, richer than the
diagnosing model), one effect at a time plus null recordings, over several scenes, seeds and
magnitudes (0.5, 1, 2 and 4 times each effect's stated detection magnitude). The diagnosis sees
only the recording and the scene. Reported per effect: top-1 accuracy (all magnitudes and at or
above the stated detection magnitude), false alarms on the nulls, parameter recovery, fit
improvement. Results: docs/figures/diagnosis_bench.json (and a table on stdout).

    python benchmarks/bench_diagnosis.py                    # full benchmark, 2 workers
    python benchmarks/bench_diagnosis.py --pilot EFFECT M1 M2 ...   # a few recordings, printed
    python benchmarks/bench_diagnosis.py --speed            # 24 x 120 x 160 and 50 x 204 x 204 timed
    python benchmarks/bench_diagnosis.py --speed-check      # the same, against the recorded times

``--speed-check`` is the speed regression guard: it runs the four timed diagnoses again (writing
nothing) and exits with status 1 when a verdict differs from the one recorded in
docs/figures/diagnosis_speed.json or a run's CPU time exceeds ``SPEED_GUARD`` times its recorded
CPU time (CPU, not wall time; still, run it on an idle machine as the recorded times were: two
torch threads on loaded cores spend more CPU time waiting on each other).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
from concealed_generator import EFFECTS, generate  # noqa: E402 (a sibling script)

#: detection magnitude of each effect, in the generator's unit (see concealed_generator.py); set
#: from one pilot recording per effect at 2x and 8x of a first guess (docs/diagnosis.md)
DETECTION = {
    "cyclic_error": 0.02,  # share of square wave in the light (truth reported in mm p-p)
    "amplitude_bias": 4.0,  # beta, mm per e-fold
    "fpn_pattern": 2.0,  # rms of the column / row delays, mm
    "vignetting": 0.02,  # light lost at the far corner (fraction)
    "temporal_drift": 1.0,  # drift over the recording, mm
    "noise_floor": 8.0,  # clock jitter, mm rms (4 before run 6: restated, docs/diagnosis.md)
    "pixel_gain": 0.01,  # rms of the quantum efficiency (fraction)
    "impulsive_pixels": 0.001,  # share of random-telegraph pixels
    "saturation": 0.01,  # share of pixels clipped
    "flying_pixels": 0.01,  # light leaked from each 4-neighbour (fraction)
    "phase_wrapping": 0.01,  # share of the scene beyond the range
    "multipath": 0.01,  # relayed / direct active light, median pixel
}
UNITS = {
    "cyclic_error": "square-wave share",
    "amplitude_bias": "mm per e-fold",
    "fpn_pattern": "mm rms",
    "vignetting": "corner loss",
    "temporal_drift": "mm over the recording",
    "noise_floor": "mm rms",
    "pixel_gain": "rms",
    "impulsive_pixels": "pixel share",
    "saturation": "pixel share",
    "flying_pixels": "leak per neighbour",
    "phase_wrapping": "scene share",
    "multipath": "relayed / direct light",
}
FACTORS = (0.5, 1.0, 2.0, 4.0)
SCENES = ("synthetic", "planar", "ramp")
H, W, T = 120, 160, 24


def scene(kind: str, seed: int):
    from tof_fpn_torch.sim import Scene, planar_scene, synthetic_scene

    if kind == "synthetic":
        return synthetic_scene(H, W, seed=seed, depth_range=(0.5, 6.0))
    if kind == "planar":
        return planar_scene(H, W, seed=seed)
    g = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W]
    d = 0.8 + 4.5 * yy / (H - 1) + 0.3 * np.sin(2 * np.pi * xx / W * g.uniform(0.5, 2))
    rho = 0.25 + 0.6 * (np.floor(xx / g.uniform(10, 25)) % 3) / 2
    t = lambda a: torch.tensor(a, dtype=torch.float32)[None, None]  # noqa: E731
    return Scene(t(d), t(rho))


def truth_value(effect: str, truth: dict):
    return {
        "cyclic_error": truth.get("peak_to_peak_mm"),
        "amplitude_bias": truth.get("bias_p10_minus_p90_mm"),
        "fpn_pattern": truth.get("rms_mm"),
        "vignetting": truth.get("corner_loss"),
        "temporal_drift": truth.get("total_mm"),
        "noise_floor": truth.get("sigma_mm"),
        "pixel_gain": truth.get("rms"),
        "impulsive_pixels": truth.get("share_frame_pixels"),
        "saturation": truth.get("share_clipped"),
        "flying_pixels": 4 * truth.get("crosstalk", 0.0),
        "phase_wrapping": truth.get("range_m"),
        "multipath": truth.get("relay_share"),
    }.get(effect)


def lens_blur_outside(sigma: float) -> float:
    """Share of a pixel's light that ``sim.LensBlur(sigma)`` sends to other pixels: ``1 - k0^2``
    for its separable sampled kernel (radius ``ceil(3 sigma)``, normalised), the quantity the
    generator's 4-neighbour crosstalk ``m`` sets to ``4 m``. (Runs 1-7 used the continuous
    Gaussian's light outside the pixel square, ``1 - erf(0.5 / (sigma sqrt 2))^2``, which the
    sampled kernel does not have: 0.46 instead of 0.26 at sigma = 0.45 px.)"""
    if sigma <= 0:
        return 0.0
    r = max(1, math.ceil(3.0 * sigma))
    k0 = 1.0 / sum(math.exp(-0.5 * (x / sigma) ** 2) for x in range(-r, r + 1))
    return 1.0 - k0 * k0


def fitted_value(effect: str, params: dict, values: dict, frames: int):
    """The fitted size of ``effect`` in the generator's unit from the report's ``params`` (the
    catalogue member's quantities, which some flexible members report too, e.g.
    ``peak_to_peak_mm``); None when the named terms do not report it (a flexible member whose
    parameters are of another form): its error is not counted."""
    try:
        return _catalogue_value(effect, params, values, frames)
    except KeyError:
        return None


def _catalogue_value(effect: str, params: dict, values: dict, frames: int):
    if effect == "cyclic_error":
        return params["peak_to_peak_mm"]
    if effect == "amplitude_bias":
        return params["bias_at_p10_amplitude_mm"] - params["bias_at_p90_amplitude_mm"]
    if effect == "fpn_pattern":
        return max(params["rms_columns_mm"], params["rms_rows_mm"])
    if effect == "vignetting":
        return 1 - params["corner_relative_illumination_percent"] / 100
    if effect == "temporal_drift":
        tau = values["temporal_drift.time_constant"]
        return abs(values["temporal_drift.depth_step"] * (1 - math.exp(-(frames - 1) / tau))) * 1e3
    if effect == "noise_floor":
        return params["sigma_mm"]
    if effect == "pixel_gain":
        return params["rms_percent"] / 100
    if effect == "impulsive_pixels":
        return params["rate_percent"] / 100
    if effect == "saturation":
        return params["share_of_pixels_clipped"]
    if effect == "flying_pixels":  # light a pixel sends elsewhere, comparable to 4 x the leak
        return lens_blur_outside(params["psf_sigma_px"])
    if effect == "phase_wrapping":
        return params["range_m"]
    if effect == "multipath":
        return params["median_relay_to_direct"]
    return None


def set_size(h: int, w: int, t: int) -> None:
    global H, W, T
    H, W, T = h, w, t


def one(job: dict) -> dict:
    torch.set_num_threads(1)
    if "size" in job:
        set_size(*job["size"])
    from tof_fpn_torch.diagnosis import diagnose
    from tof_fpn_torch.io import Recording

    sc = scene(job["scene"], job["scene_seed"])
    d = sc.depth[0, 0].double().numpy()
    r = sc.reflectance[0, 0].double().numpy()
    depth, amp, meta, truth = generate(
        d, r, frames=T, seed=job["seed"], effect=job["effect"], magnitude=job["magnitude"]
    )
    rec = Recording(torch.from_numpy(depth), torch.from_numpy(amp), meta)
    t0 = time.perf_counter()
    c0 = time.process_time()
    diag = diagnose(rec, sc, seed=job["seed"])
    out = dict(job)
    out["seconds"] = time.perf_counter() - t0
    out["cpu_seconds"] = time.process_time() - c0
    rep = diag.report
    out["found"] = [e["name"] for e in rep["effects"]]
    out["top1"] = out["found"][0] if out["found"] else "none"
    out["fit"] = rep["fit"]
    out["unexplained"] = [w["statistic"] for w in rep["unexplained"]]
    eff = job["effect"]
    if eff is not None:
        out["truth"] = truth_value(eff, truth)
        out["truth_detail"] = {k: v for k, v in truth.items() if k != "effect"}
        hit = next((e for e in rep["effects"] if e["name"] == eff), None)
        out["fitted"] = (
            fitted_value(eff, hit["params"], diag.model.values, T) if hit is not None else None
        )
    return out


def jobs(
    effects, factors, n_seeds: int, nulls: int, offset: int = 0, null_offset: int = 0
) -> list[dict]:
    """Recordings ``n_seeds`` per effect and magnitude (the scene family cycles with the seed and
    the magnitude: 6 seeds = 2 per scene family) and ``nulls`` null recordings; ``offset`` /
    ``null_offset`` shift the seeds (new recordings on the same design)."""
    out = []
    for e in effects:
        for fi, fac in enumerate(factors):
            for s in range(offset, offset + n_seeds):
                kind = SCENES[(s + fi) % len(SCENES)]
                out.append(
                    {
                        "effect": e,
                        "factor": fac,
                        "magnitude": DETECTION[e] * fac,
                        "scene": kind,
                        "scene_seed": 100 + s,
                        "seed": 1000 * fi + s,
                    }
                )
    for s in range(null_offset, null_offset + nulls):
        out.append(
            {
                "effect": None,
                "factor": 0.0,
                "magnitude": 0.0,
                "scene": SCENES[s % len(SCENES)],
                "scene_seed": 200 + s,
                "seed": 5000 + s,
            }
        )
    return out


def summary(results: list[dict]) -> dict:
    out = {}
    for e in EFFECTS:
        rs = [r for r in results if r["effect"] == e]
        if not rs:
            continue
        above = [r for r in rs if r["factor"] >= 1.0]
        rec = [
            abs(r["fitted"] - r["truth"]) / abs(r["truth"])
            for r in above
            if r.get("fitted") is not None and r.get("truth")
        ]
        gain = [
            r["fit"]["before"]["heldout_nll_per_observation"]
            - r["fit"]["after"]["heldout_nll_per_observation"]
            for r in above
        ]
        by_factor = {}
        for fac in FACTORS:
            sel = [r for r in rs if r["factor"] == fac]
            if sel:
                by_factor[str(fac)] = sum(r["top1"] == e for r in sel) / len(sel)
        out[e] = {
            "detection_magnitude": DETECTION[e],
            "unit": UNITS[e],
            "recordings": len(rs),
            "top1_all": sum(r["top1"] == e for r in rs) / len(rs),
            "top1_at_or_above_detection": sum(r["top1"] == e for r in above) / max(len(above), 1),
            "top1_by_factor": by_factor,
            "median_relative_parameter_error": float(np.median(rec)) if rec else None,
            # recordings whose parameter error counts (the named terms report the quantity)
            "parameter_errors_counted": len(rec),
            "median_heldout_nll_gain_per_observation": float(np.median(gain)) if gain else None,
            "wrong_top1": sorted({r["top1"] for r in rs if r["top1"] != e}),
            "top1_by_scene": {
                k: f"{sum(r['top1'] == e for r in rs if r['scene'] == k)}/"
                f"{sum(r['scene'] == k for r in rs)}"
                for k in SCENES
                if any(r["scene"] == k for r in rs)
            },
        }
        if e == "phase_wrapping":  # wrapped pixels clearly beyond the range, and their SNR
            out[e]["scene_factor_top1_pixels_beyond_by_2sd_snr"] = [
                [
                    r["scene"],
                    r["factor"],
                    r["top1"],
                    r["truth_detail"]["pixels_beyond_by_2_sd"],
                    round(r["truth_detail"]["beyond_snr_median"], 2),
                ]
                for r in rs
            ]
    nulls = [r for r in results if r["effect"] is None]
    out["null"] = {
        "recordings": len(nulls),
        "false_alarms": sum(r["top1"] != "none" for r in nulls),
        "false_alarm_rate": sum(r["top1"] != "none" for r in nulls) / max(len(nulls), 1),
        "named": sorted({r["top1"] for r in nulls if r["top1"] != "none"}),
    }
    secs = [r["seconds"] for r in results]
    cpu = [r["cpu_seconds"] for r in results]
    out["seconds"] = {
        "median": float(np.median(secs)),
        "max": float(np.max(secs)),
        "cpu_median": float(np.median(cpu)),
        "cpu_max": float(np.max(cpu)),
    }
    return out


#: ``--speed-check`` fails when a run's CPU time exceeds this many times its recorded one
SPEED_GUARD: float = 1.5


def speed_check(recorded_path: str, threads: int = 2) -> int:
    """The speed regression guard (module docstring): 0 when every run's verdict is the
    recorded one and its CPU time within ``SPEED_GUARD`` of the recorded, else 1."""
    import tempfile

    recorded = json.loads(Path(recorded_path).read_text())["runs"]
    with tempfile.TemporaryDirectory() as tmp:
        now = speed(str(Path(tmp) / "speed.json"), threads)["runs"]
    status = 0
    for old, new in zip(recorded, now, strict=True):
        case = f"{old['effect'] or 'null'} {old['frames']} x {old['height']} x {old['width']}"
        ratio = new["cpu_seconds"] / old["cpu_seconds"]
        ok = new["verdict"] == old["verdict"] and ratio <= SPEED_GUARD
        print(
            f"{'ok  ' if ok else 'FAIL'} {case}: verdict {new['verdict']} (recorded "
            f"{old['verdict']}), CPU {new['cpu_seconds']:.1f} s = {ratio:.2f} x recorded",
            flush=True,
        )
        status |= not ok
    return int(status)


def speed(out_path: str, threads: int = 2) -> dict:
    """One full diagnosis (default bootstrap, figures rendered) of a null recording of 24 frames
    120 x 160 and one of 50 frames 204 x 204, and of the same sizes with a 2 % scene relay
    (multipath) on the ramp, ``threads`` torch threads; load average recorded (the machine may
    be shared)."""
    import os

    from tof_fpn_torch.diagnosis import diagnose
    from tof_fpn_torch.io import Recording
    from tof_fpn_torch.sim import synthetic_scene

    res = {"threads": threads, "cpu_count": os.cpu_count(), "runs": []}
    # warm-up (imports, matplotlib, first kernels) on a 32 x 32, 4-frame recording, timed apart
    sc = synthetic_scene(32, 32, seed=1)
    depth, amp, meta, _ = generate(
        sc.depth[0, 0].double().numpy(), sc.reflectance[0, 0].double().numpy(), frames=4, seed=1
    )
    t0 = time.perf_counter()
    diagnose(Recording(torch.from_numpy(depth), torch.from_numpy(amp), meta), sc).files(True)
    res["warm_up_seconds"] = round(time.perf_counter() - t0, 2)
    # null recordings, then the slowest kind of run 8 (multipath at 2x on the ramp: every
    # candidate fitted, two terms kept, the backward pass refits)
    cases = [(h, w, t, None) for h, w, t in ((120, 160, 24), (204, 204, 50))]
    cases += [(h, w, t, "multipath") for h, w, t in ((120, 160, 24), (204, 204, 50))]
    for h, w, t, eff in cases:
        if eff is None:
            sc = synthetic_scene(h, w, seed=7, depth_range=(0.5, 6.0))
        else:
            set_size(h, w, t)
            sc = scene("ramp", 122)
        d = sc.depth[0, 0].double().numpy()
        r = sc.reflectance[0, 0].double().numpy()
        mag = 0.0 if eff is None else 2 * DETECTION[eff]
        depth, amp, meta, _ = generate(
            d, r, frames=t, seed=7 if eff is None else 1022, effect=eff, magnitude=mag
        )
        rec = Recording(torch.from_numpy(depth), torch.from_numpy(amp), meta)
        load0 = os.getloadavg()
        t0, c0 = time.perf_counter(), time.process_time()
        diag = diagnose(rec, sc, threads=threads)
        files = diag.files(figures=True)
        run = {
            "effect": eff,
            "frames": t,
            "height": h,
            "width": w,
            "seconds": round(time.perf_counter() - t0, 2),
            "cpu_seconds": round(time.process_time() - c0, 2),
            "load_average_1_5_15_before": [round(x, 2) for x in load0],
            "load_average_1_5_15_after": [round(x, 2) for x in os.getloadavg()],
            "verdict": diag.report["verdict"],
            "files": sorted(files),
        }
        print(json.dumps(run), flush=True)
        res["runs"].append(run)
    Path(out_path).write_text(json.dumps(res, indent=1) + "\n")
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--pilot", nargs="+", default=None, metavar="EFFECT_OR_MAGNITUDE")
    ap.add_argument("--seeds", type=int, default=5, help="recordings per effect and magnitude")
    ap.add_argument(
        "--seed-offset", type=int, default=0, help="first seed (runs 1-5: 0; new recordings: > 0)"
    )
    ap.add_argument("--null-offset", type=int, default=0, help="first null seed (runs 1-5: 0)")
    ap.add_argument("--nulls", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--effects", nargs="*", default=list(EFFECTS))
    ap.add_argument("--factors", nargs="*", type=float, default=list(FACTORS))
    ap.add_argument("--size", nargs=3, type=int, default=[H, W, T], metavar=("H", "W", "T"))
    ap.add_argument("--out", default=str(HERE.parent / "docs/figures/diagnosis_bench.json"))
    ap.add_argument("--speed", action="store_true", help="only the four timed diagnoses")
    ap.add_argument(
        "--speed-check",
        action="store_true",
        help="the timed diagnoses against docs/figures/diagnosis_speed.json (exit 1: slower)",
    )
    a = ap.parse_args()
    if a.speed_check:
        raise SystemExit(speed_check(str(HERE.parent / "docs/figures/diagnosis_speed.json")))
    if a.speed:
        speed(str(HERE.parent / "docs/figures/diagnosis_speed.json"))
        return
    set_size(*a.size)
    if a.pilot:
        eff = None if a.pilot[0] == "none" else a.pilot[0]
        mags = [float(x) for x in a.pilot[1:]] or [0.0]
        js = [
            {
                "effect": eff,
                "factor": 1.0,
                "magnitude": m,
                "scene": SCENES[i % 3],
                "scene_seed": 100 + i,
                "seed": i,
            }
            for i, m in enumerate(mags)
        ]
    else:
        js = jobs(a.effects, a.factors, a.seeds, a.nulls, a.seed_offset, a.null_offset)
    for j in js:
        j["size"] = list(a.size)
    if not a.pilot:
        js = interleave(js)
    t0 = time.time()
    results = []
    with ProcessPoolExecutor(max_workers=a.workers) as ex:
        for r in ex.map(one, js):
            results.append(r)
            print(
                f"{r['effect']!s:17} x{r['factor']:<4} {r['scene']:9} -> {r['top1']:17} "
                f"truth {r.get('truth')!s:.8} fitted {r.get('fitted')!s:.8} "
                f"{r['seconds']:.1f} s",
                flush=True,
            )
            if not a.pilot:  # written as it goes: a run cut short keeps what it measured
                save(a.out, results, t0, complete=len(results) == len(js))
    if not a.pilot:
        print(json.dumps(summary(results), indent=1))


def interleave(js: list[dict]) -> list[dict]:
    """Recordings in an order where a partial run is a fair sample: effect by effect at one
    seed (every effect and magnitude before the next seed), nulls spread evenly."""
    eff = [j for j in js if j["effect"] is not None]
    nul = [j for j in js if j["effect"] is None]
    eff.sort(key=lambda j: (j["seed"] % 1000, j["factor"]))
    out, step = [], max(len(eff) // max(len(nul), 1), 1)
    for i, j in enumerate(eff):
        out.append(j)
        if nul and (i + 1) % step == 0:
            out.append(nul.pop(0))
    return out + nul


def save(path: str, results: list[dict], t0: float, complete: bool) -> None:
    summ = summary(results)
    summ["wall_seconds"] = time.time() - t0
    summ["complete"] = complete
    tmp = Path(str(path) + ".tmp")
    tmp.write_text(
        json.dumps({"summary": summ, "results": results}, indent=1, default=float) + "\n"
    )
    tmp.replace(path)


if __name__ == "__main__":
    main()
