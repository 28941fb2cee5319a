"""Does ``tof-fpn diagnose`` name the effect planted by the literature generator?

The recordings come from ``benchmarks/literature_generator.py`` (``--part dev``) or
``benchmarks/literature_heldout.py`` (``--part heldout``) or ``benchmarks/literature_heldout2.py``
(``--part heldout2``): an AMCW camera written from published
physics, with effects whose forms the diagnosis was not tuned on (see those modules' docstrings for
every form and its source). For each recording the diagnosis gets the recording (depth, amplitude,
raw samples, meta) and the true scene (radial depth, reflectance); its list of effect names is
scored:

- per family: the share of recordings whose first name is the planted family ("none" if the list
  is empty);
- nulls (no effect, only the camera's shot/read noise): a false alarm is any name at all;
- "beyond the planted effect": the share of recordings naming anything other than the planted
  family.

    python benchmarks/bench_literature.py --part dev --workers 2 --json dev.json
    python benchmarks/bench_literature.py --part dev --limit 3   # a smoke run
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import literature_generator as lg  # the script's folder is on the path


def _part(part):
    if part == "dev":
        return lg.DEV_FORMS, lg.generate, 0
    if part == "heldout":
        import literature_heldout as lh

        return lh.HELDOUT_FORMS, lh.generate, lh.SEED0
    if part == "heldout2":
        import literature_heldout2 as lh2

        return lh2.HELDOUT2_FORMS, lh2.generate, lh2.SEED0
    raise ValueError(f"part must be dev, heldout or heldout2, got {part!r}")


def case_list(part, per_form, nulls, limit=None):
    forms, _, seed0 = _part(part)
    cases = lg.cases(forms, per_form, nulls, seed0)
    if limit is not None:
        cases = cases[:limit]
    return cases


def _init_worker():
    import torch

    torch.set_num_threads(1)


def to_inputs(r):
    """A generated recording as the diagnosis' inputs: (Recording, Scene)."""
    import torch

    from tof_fpn_torch.io import Recording
    from tof_fpn_torch.sim import Scene

    rec = Recording(
        torch.from_numpy(r["depth"][:, None]),
        torch.from_numpy(r["amplitude"][:, None]),
        r["meta"],
        torch.from_numpy(r["raw"]),
    )
    scene = Scene(
        torch.from_numpy(r["scene_depth"].astype("float32")[None, None]),
        torch.from_numpy(r["reflectance"].astype("float32")[None, None]),
    )
    return rec, scene


def run_case(args):
    """Generate one recording and diagnose it: a JSON-able row."""
    from tof_fpn_torch.diagnosis import diagnose

    part, family, form, seed, size = args
    _, generate, _ = _part(part)
    t0 = time.time()
    r = generate(family, form, seed, tuple(size))
    t_gen = time.time() - t0
    rec, scene = to_inputs(r)
    row = {"family": family, "form": form, "seed": seed, "truth": r["truth"]}
    t1 = time.time()
    try:
        d = diagnose(rec, scene, seed=seed)
        row["names"] = [e["name"] for e in d.report["effects"]]
    except Exception as exc:  # a crash is scored as a miss and reported
        row["names"] = []
        row["error"] = f"{type(exc).__name__}: {exc}"
    row["seconds_generate"] = round(t_gen, 2)
    row["seconds_diagnose"] = round(time.time() - t1, 2)
    return row


def score(rows):
    """Per-family / per-form top-1 shares, null false alarms, names beyond the planted effect."""
    fam = defaultdict(lambda: {"n": 0, "top1": 0, "beyond": 0})
    form = defaultdict(lambda: {"n": 0, "top1": 0, "beyond": 0})
    nulls = {"n": 0, "false_alarms": 0}
    misses = []
    for r in rows:
        names = r["names"]
        if r["family"] == "none":
            nulls["n"] += 1
            if names:
                nulls["false_alarms"] += 1
                misses.append({"family": "none", "form": "null", "seed": r["seed"], "named": names})
            continue
        first = names[0] if names else "none"
        hit = first == r["family"]
        beyond = any(n != r["family"] for n in names)
        for s in (fam[r["family"]], form[(r["family"], r["form"])]):
            s["n"] += 1
            s["top1"] += int(hit)
            s["beyond"] += int(beyond)
        if not hit:
            m = {"family": r["family"], "form": r["form"], "seed": r["seed"], "named": names}
            if "error" in r:
                m["error"] = r["error"]
            misses.append(m)
    planted = [r for r in rows if r["family"] != "none"]
    tot = {
        "recordings": len(planted),
        "top1": sum(int((r["names"] or ["none"])[0] == r["family"]) for r in planted),
        "beyond": sum(int(any(n != r["family"] for n in r["names"])) for r in planted),
    }
    for s in [*fam.values(), *form.values(), tot]:
        n = s.get("n", s.get("recordings", 0))
        s["top1_share"] = s["top1"] / n if n else None
        s["beyond_share"] = s["beyond"] / n if n else None
    nulls["false_alarm_share"] = nulls["false_alarms"] / nulls["n"] if nulls["n"] else None
    return {
        "per_family": dict(fam),
        "per_form": {f"{k[0]}/{k[1]}": v for k, v in form.items()},
        "nulls": nulls,
        "totals": tot,
        "misses": misses,
    }


def _pct(x):
    return "  -  " if x is None else f"{100 * x:5.1f}"


def print_table(sc, out=sys.stdout):
    p = lambda *a: print(*a, file=out)  # noqa: E731
    p(f"{'family':18s} {'n':>3s} {'top-1 %':>8s} {'beyond %':>9s}")
    for k, s in sorted(sc["per_family"].items()):
        p(f"{k:18s} {s['n']:3d} {_pct(s['top1_share']):>8s} {_pct(s['beyond_share']):>9s}")
    p("")
    p(f"{'family/form':46s} {'n':>3s} {'top-1 %':>8s} {'beyond %':>9s}")
    for k, s in sorted(sc["per_form"].items()):
        p(f"{k:46s} {s['n']:3d} {_pct(s['top1_share']):>8s} {_pct(s['beyond_share']):>9s}")
    p("")
    t = sc["totals"]
    n = sc["nulls"]
    p(
        f"planted: {t['top1']}/{t['recordings']} first name right ({_pct(t['top1_share'])} %), "
        f"{t['beyond']} name something beyond ({_pct(t['beyond_share'])} %)"
    )
    p(f"nulls: {n['false_alarms']}/{n['n']} false alarms ({_pct(n['false_alarm_share'])} %)")
    if sc["misses"]:
        p("\nmisses (planted -> named):")
        for m in sc["misses"]:
            extra = f"  [{m['error']}]" if "error" in m else ""
            p(f"  {m['family']}/{m['form']} seed {m['seed']}: {m['named'] or ['none']}{extra}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--part", choices=["dev", "heldout", "heldout2"], default="dev")
    ap.add_argument("--per-form", type=int, default=2)
    ap.add_argument("--nulls", type=int, default=8)
    ap.add_argument("--size", type=int, nargs=3, default=[120, 160, 24], metavar=("H", "W", "T"))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--limit", type=int, default=None, help="only the first N recordings")
    a = ap.parse_args(argv)
    cases = case_list(a.part, a.per_form, a.nulls, a.limit)
    jobs = [(a.part, f, fo, s, a.size) for f, fo, s in cases]
    t0 = time.time()
    rows = []
    if a.workers > 1:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        with mp.get_context("spawn").Pool(a.workers, initializer=_init_worker) as pool:
            for row in pool.imap(run_case, jobs):
                rows.append(row)
                print(
                    f"{row['family']}/{row['form']} seed {row['seed']}: {row['names']}", flush=True
                )
    else:
        _init_worker()
        for job in jobs:
            row = run_case(job)
            rows.append(row)
            print(f"{row['family']}/{row['form']} seed {row['seed']}: {row['names']}", flush=True)
    sc = score(rows)
    print()
    print_table(sc)
    wall = time.time() - t0
    print(f"\n{len(rows)} recordings in {wall:.0f} s ({a.workers} workers)")
    if a.json is not None:
        out = {
            "part": a.part,
            "per_form": a.per_form,
            "nulls": a.nulls,
            "size": a.size,
            "limit": a.limit,
            "wall_seconds": round(wall, 1),
            "score": sc,
            "rows": rows,
        }
        a.json.write_text(json.dumps(out, indent=1))
    return sc


if __name__ == "__main__":
    main()
