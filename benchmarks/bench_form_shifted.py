"""Form-shifted benchmark of ``tof_fpn_torch.diagnosis``: effects in other functional forms.

Recordings come from ``benchmarks/form_shifted_generator.py`` (NumPy, written without reading the
diagnosis): 13 planted effects (``readout_pattern`` is expected to be named ``fpn_pattern``), two
forms (A, B) each, on four scene models (room corner, steps, solids, polygons) that are not the
catalogue's, at 1x and 2x a detection magnitude per effect and form, plus null recordings. The
diagnosis sees the recording (depth, amplitude, meta; the raw samples with ``--raw``) and the
scene. Reported per effect and form: top-1 (the planted name first), recordings that name more
than the planted effect, misses and what was named; nulls: false alarms. Results:
docs/figures/diagnosis_form_shifted.json and .md (the table, also on stdout).

Detection magnitudes (:data:`DETECTION`): for the effects with an ``snr`` (see the generator's
docstring) the magnitude at which the median ``snr`` over 8 development recordings (2 per scene
model, seeds 10000-10007, 120 x 160, 24 frames) is 3, i.e. the temporal-mean signature is 3 x the
per-pixel temporal-mean noise over the affected region (``--calibrate`` recomputes them); for the
share effects a share stated by hand (impulsive 0.1 % of frame-pixels, saturation 1 % of pixels,
wrapping 1 % of the scene, flying A 25 % of the depth-edge pixels mixed).

Seeds: development and pilots used 10000-19999 (``--pilot`` defaults to 10000); the benchmark's
default range starts at 120000: the published result (docs/figures/diagnosis_form_shifted.md),
never run during development; a run on new code needs unseen seeds (``--seed-offset 130000`` and
on). Not unseen: 70000 and 75000 (a check of ``--resume`` at 24 x 32 px) and 80000-119999 (runs
of earlier code).

    python benchmarks/bench_form_shifted.py --workers 2            # 13 x 2 x 2 x 6 + 24 nulls
    python benchmarks/bench_form_shifted.py --workers 2 --resume   # go on with a run cut short
    python benchmarks/bench_form_shifted.py --pilot multipath B     # a few recordings, printed
    python benchmarks/bench_form_shifted.py --calibrate             # the 1x magnitudes' snr
    python benchmarks/bench_form_shifted.py --table                 # table and totals of --out
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
import form_shifted_generator as fsg  # noqa: E402 (a sibling script)

#: 1x magnitude per (effect, form), in the generator's unit (its docstring); see the docstring
DETECTION: dict[tuple[str, str], float] = {
    ("amplitude_bias", "A"): 150.0,  # mm, bias of the weakest pixels
    ("amplitude_bias", "B"): 80.0,
    ("cyclic_error", "A"): 70.0,  # mm peak to peak
    ("cyclic_error", "B"): 75.0,
    ("fpn_pattern", "A"): 21.0,  # mm RMS
    ("fpn_pattern", "B"): 21.0,
    ("readout_pattern", "A"): 17.0,  # e- RMS |Z|
    ("readout_pattern", "B"): 18.0,
    ("pixel_gain", "A"): 0.017,  # RMS gain
    ("pixel_gain", "B"): 0.02,  # gain deficit of the weak pixels
    ("impulsive_pixels", "A"): 0.001,  # share of frame-pixels
    ("impulsive_pixels", "B"): 0.001,
    ("saturation", "A"): 0.01,  # share of pixels over the well / knee
    ("saturation", "B"): 0.01,
    ("flying_pixels", "A"): 0.25,  # share of depth-edge pixels mixed
    ("flying_pixels", "B"): 0.035,  # footprint excess width, px
    ("multipath", "A"): 0.08,  # specular share
    ("multipath", "B"): 0.025,  # median relayed / direct light
    ("noise_floor", "A"): 31.0,  # mm RMS
    ("noise_floor", "B"): 23.0,
    ("phase_wrapping", "A"): 0.01,  # share of the scene beyond the range
    ("phase_wrapping", "B"): 0.01,
    ("temporal_drift", "A"): 69.0,  # mm peak to peak
    ("temporal_drift", "B"): 50.0,
    ("vignetting", "A"): 0.06,  # largest light loss
    ("vignetting", "B"): 0.028,
}
SHARE_SET = {"impulsive_pixels", "saturation", "phase_wrapping"}  # magnitudes set by hand
FACTORS = (1.0, 2.0)
H, W, T = 120, 160, 24
FINAL_SEEDS, DEV_SEEDS = 120000, 10000


def make_job(effect, form, factor, seed, kind, size, raw=False) -> dict:
    mag = DETECTION[(effect, form)] * factor if effect else 0.0
    return {
        "effect": effect,
        "form": form if effect else None,
        "factor": factor,
        "magnitude": mag,
        "scene": kind,
        "seed": seed,
        "size": list(size),
        "raw": raw,
    }


def jobs(effects, forms, factors, per_cell, nulls, offset, size, raw=False) -> list[dict]:
    """``per_cell`` recordings per effect, form and factor (scene models cycling), then
    ``nulls`` null recordings; seeds ``offset``, ``offset + 1``, ... (nulls from offset + 5000)."""
    out, s = [], offset
    for e in effects:
        for fi, form in enumerate(forms):
            for ki, fac in enumerate(factors):
                for i in range(per_cell):
                    kind = fsg.SCENES[(i + ki + fi) % len(fsg.SCENES)]
                    out.append(make_job(e, form, fac, s, kind, size, raw))
                    s += 1
    for i in range(nulls):
        out.append(make_job(None, "A", 0.0, offset + 5000 + i, fsg.SCENES[i % 4], size, raw))
    return out


def record(job: dict):
    """The generator's output and the scene (torch) of one job."""
    from tof_fpn_torch.sim import Scene

    h, w, t = job["size"]
    d, rho, info = fsg.scene_model(job["scene"], h, w, job["seed"])
    out = fsg.generate(
        d,
        rho,
        effect=job["effect"],
        form=job["form"] or "A",
        magnitude=job["magnitude"],
        frames=t,
        seed=job["seed"],
        info=info,
    )
    ten = lambda a: torch.tensor(a, dtype=torch.float32)[None, None]  # noqa: E731
    return out, Scene(ten(out["scene_depth"]), ten(rho))


def one(job: dict) -> dict:
    torch.set_num_threads(1)
    from tof_fpn_torch.diagnosis import diagnose
    from tof_fpn_torch.io import Recording

    gen, sc = record(job)
    raw = torch.from_numpy(gen["raw"]) if job["raw"] else None
    rec = Recording(
        torch.from_numpy(gen["depth"]), torch.from_numpy(gen["amplitude"]), gen["meta"], raw
    )
    t0, c0 = time.perf_counter(), time.process_time()
    diag = diagnose(rec, sc, seed=job["seed"])
    out = dict(job)
    out["seconds"] = time.perf_counter() - t0
    out["cpu_seconds"] = time.process_time() - c0
    out["found"] = [e["name"] for e in diag.report["effects"]]
    out["top1"] = out["found"][0] if out["found"] else "none"
    out["scores"] = [
        {k: e.get(k) for k in ("name", "terms", "score", "drop_delta_aic")}
        for e in diag.report["effects"]
    ]
    out["expected"] = fsg.EXPECTED.get(job["effect"]) if job["effect"] else "none"
    out["truth"] = {k: v for k, v in gen["truth"].items() if k != "effect"}
    return out


def summary(results: list[dict]) -> dict:
    cells: dict[str, dict] = {}
    for r in results:
        if r["effect"] is None:
            continue
        key = f"{r['effect']} {r['form']}"
        c = cells.setdefault(
            key, {"recordings": 0, "top1": 0, "by_factor": {}, "extra": 0, "alone": 0}
        )
        c.setdefault("misses", [])
        c["recordings"] += 1
        hit = r["top1"] == r["expected"]
        c["top1"] += hit
        f = c["by_factor"].setdefault(str(r["factor"]), [0, 0])
        f[0] += hit
        f[1] += 1
        c["extra"] += r["expected"] in r["found"] and len(r["found"]) > 1
        c["alone"] += r["found"] == [r["expected"]]
        if not hit:
            c["misses"].append({"scene": r["scene"], "factor": r["factor"], "found": r["found"]})
        c.setdefault("snr", []).append(r["truth"].get("snr"))
        c.setdefault("effect_size", []).append(r["truth"].get("effect_size"))
    for c in cells.values():
        for k in ("snr", "effect_size"):
            vals = [v for v in c.pop(k) if v is not None]
            c[f"median_{k}"] = float(np.median(vals)) if vals else None
    nulls = [r for r in results if r["effect"] is None]
    named = [r for r in nulls if r["found"]]
    return {
        "cells": cells,
        "null": {
            "recordings": len(nulls),
            "false_alarms": len(named),
            "named": sorted({n for r in named for n in r["found"]}),
        },
        "seconds_median": float(np.median([r["seconds"] for r in results])) if results else None,
    }


def lower_bound(k: int, n: int, level: float = 0.95) -> float:
    """One-sided Clopper-Pearson lower bound of a rate seen ``k`` times in ``n``."""
    from scipy.stats import beta

    return 0.0 if k == 0 else float(beta.ppf(1.0 - level, k, n - k + 1))


def upper_bound(k: int, n: int, level: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper bound of a rate seen ``k`` times in ``n``."""
    from scipy.stats import beta

    return 1.0 if k == n else float(beta.ppf(level, k + 1, n - k))


def totals(summ: dict) -> dict:
    """Over all effects: top-1, per effect (both forms), recordings naming only the planted
    effect, null false alarms; with the one-sided 95 % Clopper-Pearson bounds."""
    cells = summ["cells"].items()
    n = sum(c["recordings"] for _, c in cells)
    top1 = sum(c["top1"] for _, c in cells)
    alone = sum(c["alone"] for _, c in cells)
    per_effect: dict[str, list[int]] = {}
    for key, c in cells:
        e = per_effect.setdefault(key.split()[0], [0, 0])
        e[0] += c["top1"]
        e[1] += c["recordings"]
    worst = min(per_effect.items(), key=lambda kv: kv[1][0] / kv[1][1]) if per_effect else None
    nul = summ["null"]
    return {
        "recordings": n,
        "top1": top1,
        "top1_lower": lower_bound(top1, n) if n else None,
        "per_effect": per_effect,
        "worst_effect": worst[0] if worst else None,
        "worst_effect_lower": lower_bound(*worst[1]) if worst else None,
        "alone": alone,
        "alone_lower": lower_bound(alone, n) if n else None,
        "nulls": nul["recordings"],
        "false_alarms": nul["false_alarms"],
        "false_alarm_upper": (
            upper_bound(nul["false_alarms"], nul["recordings"]) if nul["recordings"] else None
        ),
    }


def totals_text(t: dict) -> str:
    if not t["recordings"]:
        return ""
    by = ", ".join(f"{e} {k}/{m}" for e, (k, m) in t["per_effect"].items())
    lines = [
        f"Top-1 {t['top1']}/{t['recordings']} ({100 * t['top1'] / t['recordings']:.1f} %, "
        f">= {100 * t['top1_lower']:.1f} %); by effect: {by}; lowest {t['worst_effect']} "
        f"(>= {100 * t['worst_effect_lower']:.0f} %).",
        f"Only the planted effect named: {t['alone']}/{t['recordings']} "
        f"({100 * t['alone'] / t['recordings']:.1f} %, >= {100 * t['alone_lower']:.1f} %).",
    ]
    if t["nulls"]:
        lines.append(
            f"False alarms: {t['false_alarms']}/{t['nulls']} nulls "
            f"(rate <= {100 * t['false_alarm_upper']:.1f} %)."
        )
    lines.append("Bounds: one-sided 95 % Clopper-Pearson.")
    return "\n".join(lines) + "\n"


def table(summ: dict) -> str:
    rows = [
        "| effect | form | 1x magnitude | top-1 | by factor | extra names | misses (named) | "
        "median snr | median effect size |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for key, c in summ["cells"].items():
        e, form = key.split()
        misses = "; ".join(
            f"{m['scene']} {m['factor']:g}x: {', '.join(m['found']) or 'none'}" for m in c["misses"]
        )
        fac = ", ".join(f"{k}x {v[0]}/{v[1]}" for k, v in c["by_factor"].items())
        snr = "" if c["median_snr"] is None else f"{c['median_snr']:.1f}"
        size = "" if c["median_effect_size"] is None else f"{c['median_effect_size']:.4g}"
        rows.append(
            f"| {e} | {form} | {DETECTION[(e, form)]:g} | {c['top1']}/{c['recordings']} | {fac} | "
            f"{c['extra']} | {misses} | {snr} | {size} |"
        )
    n = summ["null"]
    rows.append(
        f"| null | | | {n['recordings'] - n['false_alarms']}/{n['recordings']} named none | | | "
        f"{', '.join(n['named'])} | | |"
    )
    return "\n".join(rows) + "\n\n" + totals_text(totals(summ))


def save(out: str, results: list[dict], t0: float, complete: bool) -> dict:
    summ = summary(results)
    summ["wall_seconds"] = time.time() - t0
    summ["complete"] = complete
    path = Path(out)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(
        json.dumps({"summary": summ, "results": results}, indent=1, default=float) + "\n"
    )
    tmp.replace(path)
    path.with_suffix(".md").write_text(table(summ))
    return summ


def calibrate(size, n: int = 8) -> dict:
    """Median ``snr`` at 1x over ``n`` development recordings per effect and form (2 per scene
    model), and the magnitude that would give 3 (linear in the magnitude; noise: quadratic)."""
    out = {}
    for (e, form), mag in DETECTION.items():
        if e in SHARE_SET or (e, form) == ("flying_pixels", "A"):
            continue
        snrs = []
        for i in range(n):
            job = make_job(e, form, 1.0, DEV_SEEDS + i, fsg.SCENES[i % 4], size)
            snrs.append(record(job)[0]["truth"].get("snr"))
        med = float(np.median(snrs))
        power = 0.5 if e == "noise_floor" else 1.0
        out[f"{e} {form}"] = {
            "magnitude": mag,
            "median_snr": med,
            "for_3": mag * (3 / med) ** power,
        }
        print(
            f"{e:17} {form} {mag:8g} snr {med:6.2f} -> {out[f'{e} {form}']['for_3']:.4g}",
            flush=True,
        )
    return out


def line(r: dict) -> str:
    """One printed line per recording."""
    tr, found = r["truth"], ", ".join(r["found"]) or "none"
    return (
        f"{r['effect']!s:17} {r['form']!s:4} x{r['factor']:<3g} {r['scene']:8} seed {r['seed']} "
        f"-> {found} | size {tr.get('effect_size')!s:.7} snr {tr.get('snr')!s:.5} "
        f"{r['seconds']:.1f} s"
    )


def parse():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--effects", nargs="*", default=list(fsg.EFFECTS))
    ap.add_argument("--forms", nargs="*", default=list(fsg.FORMS))
    ap.add_argument("--factors", nargs="*", type=float, default=list(FACTORS))
    ap.add_argument(
        "--per-cell",
        type=int,
        default=None,
        help="recordings per effect, form, factor (6; pilot 1)",
    )
    ap.add_argument("--nulls", type=int, default=24)
    ap.add_argument("--seed-offset", type=int, default=None, help="default 120000 (pilot 10000)")
    ap.add_argument("--size", default=f"{H}x{W}", help="HxW")
    ap.add_argument("--frames", type=int, default=T)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--raw", action="store_true", help="give the diagnosis the raw samples")
    ap.add_argument("--pilot", nargs=2, metavar=("EFFECT", "FORM"), default=None)
    ap.add_argument("--calibrate", action="store_true")
    ap.add_argument(
        "--table",
        action="store_true",
        help="print the table and totals of the recordings in --out (and rewrite its .md); no run",
    )
    ap.add_argument(
        "--resume",
        action="store_true",
        help="keep the recordings already in --out (same jobs) and run only the others",
    )
    ap.add_argument("--out", default=str(HERE.parent / "docs/figures/diagnosis_form_shifted.json"))
    return ap.parse_args()


def _job_key(job: dict) -> tuple:
    """What makes a recording: effect, form, magnitude, seed, scene model, size, raw."""
    return (
        job["effect"],
        job["form"],
        float(job["magnitude"]),
        int(job["seed"]),
        job["scene"],
        tuple(job["size"]),
        bool(job["raw"]),
    )


def main() -> None:
    a = parse()
    h, w = (int(x) for x in a.size.lower().split("x"))
    size = (h, w, a.frames)
    if a.calibrate:
        print(json.dumps(calibrate(size), indent=1))
        return
    if a.table:
        summ = summary(json.loads(Path(a.out).read_text())["results"])
        Path(a.out).with_suffix(".md").write_text(table(summ))
        print(table(summ))
        return
    if a.per_cell is None:
        a.per_cell = 1 if a.pilot else 6
    if a.pilot:
        offset = DEV_SEEDS if a.seed_offset is None else a.seed_offset
        eff = None if a.pilot[0] == "none" else a.pilot[0]
        if eff is None:
            js = jobs([], [], [], 0, a.per_cell, offset, size, a.raw)
        else:
            js = jobs([eff], [a.pilot[1]], a.factors, a.per_cell, 0, offset, size, a.raw)
    else:
        offset = FINAL_SEEDS if a.seed_offset is None else a.seed_offset
        js = jobs(a.effects, a.forms, a.factors, a.per_cell, a.nulls, offset, size, a.raw)
    t0, results = time.time(), []
    if a.resume and Path(a.out).exists():
        done = {_job_key(r): r for r in json.loads(Path(a.out).read_text())["results"]}
        results = [done[_job_key(j)] for j in js if _job_key(j) in done]
        js_all, js = js, [j for j in js if _job_key(j) not in done]
        print(f"resuming: {len(results)} of {len(js_all)} recordings already in {a.out}")
    n_jobs = len(js) + len(results)
    with ProcessPoolExecutor(max_workers=a.workers) as ex:
        for r in ex.map(one, js):
            results.append(r)
            print(line(r), flush=True)
            if not a.pilot:  # written as it goes: a run cut short keeps what it measured
                save(a.out, results, t0, complete=len(results) == n_jobs)
    print(table(summary(results)))


if __name__ == "__main__":
    main()
