"""Score ``tof-fpn clean`` on camera folders against their truth.

For every (scene family x pattern kind x dev seed) of the grid, the folder is written by
:func:`camera_folders.make_folder` (``frames/`` + ``truth.npz``), cleaned by
``python -m tof_fpn_torch clean FRAMES OUT --quiet --no-figure --threads 1`` (the default stage,
plus any ``--extra`` flags) in a subprocess, and every cleaned frame is read back and scored
against the true depth. Two references are scored the same way on the same pixels:

- ``oracle``: the input minus the true pattern's depth effect (truth ``pattern_frames``, else
  ``pattern``): what a perfect pattern remover would give; its gain is the ceiling.
- ``basic``: BaSiC (Peng et al., "A BaSiC tool for background and shading correction of optical
  microscopy images", Nat. Commun. 8, 2017; package ``basicpy-uncapped``), its flat field and
  dark field fitted on the folder's depth frames (``get_darkfield=True``, invalid pixels given
  weight 0 and filled with the frame's median) and applied to them, ``(I - D) / S``.
- ``basic_level``: the same with the dark field's mean added back, ``(I - D) / S + mean(D)``:
  BaSiC's fields are fitted to microscope shading, so on depth frames its dark field takes the
  scene's level with it; this variant keeps the level and scores only the shape it removes.

Scored pixels: valid in the input, in the output and in the truth, and not a mixed ("flying")
pixel of the truth (a mixed pixel's error is the mixing, not the fixed pattern). Per frame:
``rms_in``, ``rms_out`` (mm) and the gain ``20 log10(rms_in / rms_out)`` dB.

Reported per pattern kind and per scene family: mean gain (dB) of clean / oracle / BaSiC; the
share of frames the cleaner made worse than its input by more than 2 % in RMS (the "never hurts"
rule); for stripe-free (``none``) folders the share of frames whose output files are
byte-identical to the input; and the frames that got worse although their manifest record reports
a stripe reduction of at least 1 dB (a record that lies). Overall: the mean clean gain on striped
folders as a percentage of the oracle's on the same frames. Frames without a cleaned output (the
clean run failed) are counted as failed, with the run's error, and left out of the clean means.

Only dev seeds (< ``camera_folders.HELD_OUT_START``) are accepted, unless ``--held-out`` is given:
the held-out seeds are run once, at the end, on the final code, and reported whatever they say.

``python benchmarks/bench_folders.py --seeds 0 --frames 6 --out /tmp/folders_bench.json``
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import camera_folders as cf
import numpy as np

#: a frame "got worse" when its output RMS exceeds the input's by more than this share
WORSE_TOL = 0.02
#: a record "claims a stripe reduction" when an axis' stripe energy fell by at least this, dB
CLAIM_DB = 1.0
METHODS = ("clean", "oracle", "basic", "basic_level")


# ----------------------------------------------------------------------------------------------
# scoring (pure functions, tested in benchmarks/tests/test_bench_folders.py)


def score_mask(inp_mm: np.ndarray, out_mm: np.ndarray, truth_ok: np.ndarray) -> np.ndarray:
    """Pixels scored: finite (valid) in input and output, and valid in the truth."""
    return np.isfinite(inp_mm) & np.isfinite(out_mm) & truth_ok


def rms(err: np.ndarray) -> float:
    """Root mean square of ``err`` (NaN for an empty array)."""
    err = np.asarray(err, float)
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")


def gain_db(rms_in: float, rms_out: float) -> float:
    """``20 log10(rms_in / rms_out)``: positive when the output is closer to the truth."""
    if not (rms_in > 0 and rms_out > 0):
        if rms_in == rms_out:
            return 0.0
        return float("inf") if rms_out == 0 else float("-inf")
    return 20.0 * math.log10(rms_in / rms_out)


def worse(rms_in: float, rms_out: float, tol: float = WORSE_TOL) -> bool:
    """True when the output's RMS error exceeds the input's by more than ``tol`` (share)."""
    return bool(rms_out > rms_in * (1.0 + tol))


def score_frame(inp_mm, out_mm, true_mm, truth_ok) -> dict:
    """RMS error (mm) of input and output against the truth over :func:`score_mask`, and the
    gain in dB."""
    m = score_mask(inp_mm, out_mm, truth_ok & np.isfinite(true_mm))
    r_in = rms(inp_mm[m] - true_mm[m])
    r_out = rms(out_mm[m] - true_mm[m])
    return {
        "pixels": int(m.sum()),
        "rms_in": r_in,
        "rms_out": r_out,
        "gain_db": gain_db(r_in, r_out),
    }


def claimed_reduction_db(report: dict | None) -> float | None:
    """The largest stripe-energy reduction a manifest ``report`` states over its axes, dB
    (``10 log10(before_mm2 / after_mm2)``); None when it states none."""
    if not report:
        return None
    best = None
    for axis in ("columns", "rows"):
        s = (report.get("stripes") or {}).get(axis)
        if not s:
            continue
        before, after = s.get("before_mm2"), s.get("after_mm2")
        if before is None or after is None or not before > 0:
            continue
        db = float("inf") if after <= 0 else 10.0 * math.log10(before / after)
        best = db if best is None else max(best, db)
    return best


def lying_record(rms_in: float, rms_out: float, report: dict | None) -> bool:
    """True when the frame got worse (:func:`worse`) but its record claims a stripe reduction
    of at least :data:`CLAIM_DB`."""
    claim = claimed_reduction_db(report)
    return worse(rms_in, rms_out) and claim is not None and claim >= CLAIM_DB


def same_bytes(a, b) -> bool:
    """True when the two files hold the same bytes."""
    return Path(a).read_bytes() == Path(b).read_bytes()


def read_manifest(path) -> dict:
    """``file -> report`` of the ``done`` records of a ``manifest.jsonl`` (the last one wins)."""
    out = {}
    p = Path(path)
    if not p.exists():
        return out
    for line in p.read_text().splitlines():
        if not line.strip():
            continue
        rec = json.loads(line)
        if rec.get("status") == "done" and "file" in rec:
            out[rec["file"]] = rec.get("report")
    return out


def _mean(xs) -> float | None:
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return float(np.mean(xs)) if xs else None


def summarise(rows: list[dict]) -> dict:
    """Aggregate frame rows (one per frame: family, pattern, gains, flags) into a group summary."""
    s = {
        "folders": len({(r["family"], r["pattern"], r["seed"]) for r in rows}),
        "frames": len(rows),
    }
    for m in METHODS:
        s[f"gain_{m}_db"] = _mean(r.get(f"gain_{m}_db") for r in rows)
    scored = [r for r in rows if r.get("worse_clean") is not None]
    s["worse_share_clean"] = sum(r["worse_clean"] for r in scored) / len(scored) if scored else None
    s["worse_frames_clean"] = [
        f"{r['family']}/{r['pattern']}/s{r['seed']}/{r['stem']}" for r in scored if r["worse_clean"]
    ]
    bs = [r for r in rows if r.get("worse_basic") is not None]
    s["worse_share_basic"] = sum(r["worse_basic"] for r in bs) / len(bs) if bs else None
    bl = [r for r in rows if r.get("worse_basic_level") is not None]
    s["worse_share_basic_level"] = sum(r["worse_basic_level"] for r in bl) / len(bl) if bl else None
    s["lying_records"] = [
        f"{r['family']}/{r['pattern']}/s{r['seed']}/{r['stem']}" for r in rows if r.get("lying")
    ]
    eq = [r["same_bytes"] for r in rows if r.get("same_bytes") is not None]
    s["same_bytes_share"] = sum(eq) / len(eq) if eq else None
    # frames without a cleaned output (the clean run failed): not in the clean means
    s["failed_frames"] = [
        f"{r['family']}/{r['pattern']}/s{r['seed']}/{r['stem']}"
        for r in rows
        if r.get("gain_clean_db") is None
    ]
    s["gain_oracle_paired_db"] = _mean(
        r.get("gain_oracle_db") for r in rows if r.get("gain_clean_db") is not None
    )
    return s


# ----------------------------------------------------------------------------------------------
# one folder


def _read_mm(depth_png: Path) -> np.ndarray:
    from tof_fpn_torch.io import read_pair

    amp = depth_png.with_name(depth_png.name.replace("_depth.png", "_amplitude.png"))
    d, _ = read_pair(depth_png, amp, allow_empty=True)
    return np.round(d[:, 0].numpy().astype(np.float64) * 1000.0)[0]


def basic_correct(depth_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BaSiC flat + dark field fitted on the stack (T, H, W) of depth frames (mm, NaN invalid),
    applied to it: ``((I - D) / S, (I - D) / S + mean(D))``; NaN stays NaN."""
    import torch
    from basicpy import BaSiC

    torch.set_num_threads(1)
    valid = np.isfinite(depth_mm)
    med = np.array(
        [np.median(f[v]) if v.any() else 0.0 for f, v in zip(depth_mm, valid, strict=True)]
    )
    fill = np.where(valid, depth_mm, med[:, None, None])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = BaSiC(get_darkfield=True)
        b.fit(fill, fitting_weight=valid.astype(np.float64))
        out = np.asarray(b.transform(fill, use_tqdm=False), np.float64)
    out = np.where(valid, out, np.nan)
    return out, out + float(np.mean(b.darkfield))


def run_folder(job: dict) -> list[dict]:
    """Make, clean and score one folder; one row per frame."""
    fam, pat, seed = job["family"], job["pattern"], job["seed"]
    if cf.split(seed) != "dev" and not job.get("held_out"):
        raise ValueError(f"seed {seed} is held out; use dev seeds < {cf.HELD_OUT_START}")
    root = Path(job["work"]) / f"{fam}__{pat}__s{seed}"
    if root.exists():
        shutil.rmtree(root)
    t0 = time.perf_counter()
    truth = cf.make_folder(root, fam, pat, seed, job["frames"], *job["size"])
    t_make = time.perf_counter() - t0
    frames, out = root / "frames", root / "out"
    cmd = [
        sys.executable,
        "-m",
        "tof_fpn_torch",
        "clean",
        str(frames),
        str(out),
        "--quiet",
        "--no-figure",
        "--threads",
        "1",
        *job["extra"],
    ]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    t_clean = time.perf_counter() - t0
    reports = read_manifest(out / "manifest.jsonl")

    stems = [str(s) for s in truth["stems"]]
    inp = np.stack([_read_mm(frames / f"{s}_depth.png") for s in stems])
    true_mm = truth["depth"] * 1000.0
    truth_ok = truth["valid"] & ~truth["flying"] & np.isfinite(truth["depth"])
    pat_frames = truth.get("pattern_frames")
    if pat_frames is None:
        pat_frames = np.broadcast_to(truth["pattern"], inp.shape)
    oracle = inp - pat_frames * 1000.0

    t_basic = None
    basic = basic_level = None
    if job["basic"]:
        t0 = time.perf_counter()
        try:
            basic, basic_level = basic_correct(inp)
        except Exception as e:  # noqa: BLE001 - reported, the rest of the folder still scored
            job.setdefault("errors", []).append(f"basic: {type(e).__name__}: {e}")
        t_basic = time.perf_counter() - t0

    rows = []
    for i, s in enumerate(stems):
        row = {
            "family": fam,
            "pattern": pat,
            "seed": seed,
            "stem": s,
            "shape": list(inp.shape[1:]),
            "t_make_s": t_make,
            "t_clean_s": t_clean,
            "t_basic_s": t_basic,
            "clean_rc": proc.returncode,
        }
        out_png = out / f"{s}_depth.png"
        if out_png.exists():
            c = score_frame(inp[i], _read_mm(out_png), true_mm[i], truth_ok[i])
            rep = reports.get(f"{s}_depth.png")
            row.update(
                rms_in_mm=c["rms_in"],
                rms_clean_mm=c["rms_out"],
                gain_clean_db=c["gain_db"],
                pixels=c["pixels"],
                worse_clean=worse(c["rms_in"], c["rms_out"]),
                claimed_db=claimed_reduction_db(rep),
                lying=lying_record(c["rms_in"], c["rms_out"], rep),
            )
            if pat == "none":
                row["same_bytes"] = same_bytes(frames / f"{s}_depth.png", out_png) and same_bytes(
                    frames / f"{s}_amplitude.png", out / f"{s}_amplitude.png"
                )
        else:
            row["error"] = (proc.stderr or "")[-500:] or "no output"
        o = score_frame(inp[i], oracle[i], true_mm[i], truth_ok[i])
        row.update(rms_oracle_mm=o["rms_out"], gain_oracle_db=o["gain_db"])
        if basic is not None:
            b = score_frame(inp[i], basic[i], true_mm[i], truth_ok[i])
            bl = score_frame(inp[i], basic_level[i], true_mm[i], truth_ok[i])
            row.update(
                rms_basic_mm=b["rms_out"],
                gain_basic_db=b["gain_db"],
                worse_basic=worse(b["rms_in"], b["rms_out"]),
                rms_basic_level_mm=bl["rms_out"],
                gain_basic_level_db=bl["gain_db"],
                worse_basic_level=worse(bl["rms_in"], bl["rms_out"]),
            )
        if job.get("errors"):
            row["errors"] = job["errors"]
        rows.append(row)
    if not job["keep"]:
        shutil.rmtree(root, ignore_errors=True)
    return rows


# ----------------------------------------------------------------------------------------------
# the grid


def _fmt(x, spec="6.2f"):
    return f"{x:{spec}}" if x is not None else " " * (int(spec.split(".")[0]) - 1) + "-"


def table(result: dict) -> str:
    """The printed table: one line per pattern kind, then per family, then overall."""
    head = (
        f"{'group':22s} {'folders':>7s} {'frames':>6s} {'clean':>6s} {'oracle':>6s} "
        f"{'basic':>6s} {'b_lvl':>6s} {'worse%':>6s} {'lying':>5s} {'same':>5s} {'failed':>6s}"
    )
    lines = [
        head + "   (gains: mean dB over frames; worse% = clean frames > +2 % RMS; lying = worse"
        " frames whose record claims >= 1 dB; same = none: bytes equal; failed = frames without"
        " output)"
    ]
    for title, groups in (("pattern", result["by_pattern"]), ("family", result["by_family"])):
        lines.append(f"-- by {title}")
        for k, s in groups.items():
            ws = s["worse_share_clean"]
            lines.append(
                f"{k:22s} {s['folders']:7d} {s['frames']:6d} {_fmt(s['gain_clean_db'])} "
                f"{_fmt(s['gain_oracle_db'])} {_fmt(s['gain_basic_db'])} "
                f"{_fmt(s['gain_basic_level_db'])} "
                f"{_fmt(None if ws is None else 100 * ws, '6.1f')} {len(s['lying_records']):5d} "
                f"{_fmt(s['same_bytes_share'], '5.2f')} {len(s['failed_frames']):6d}"
            )
    o = result["overall"]
    lines.append(
        f"-- striped folders: clean {_fmt(o['gain_clean_db'])} dB, oracle "
        f"{_fmt(o['gain_oracle_db'])} dB ({_fmt(o['gain_oracle_paired_db'])} dB on the frames"
        f" cleaned), clean = {_fmt(o['clean_pct_of_oracle'], '5.1f')} % of oracle; basic {_fmt(o['gain_basic_db'])} dB, basic_level "
        f"{_fmt(o['gain_basic_level_db'])} dB"
    )
    fails = {}
    for r in result["frames"]:
        if r.get("error"):
            key = f"{r['family']}/{r['pattern']}/s{r['seed']}"
            fails.setdefault(key, r["error"].strip().splitlines()[-1][:200])
    for key, err in fails.items():
        lines.append(f"-- FAILED {key}: {err}")
    t = result["timing"]
    lines.append(
        f"-- time per folder: make {t['make_s']:.1f} s, clean {t['clean_s']:.1f} s, "
        f"basic {_fmt(t['basic_s'], '4.1f')} s (mean over {t['folders']} folders)"
    )
    return "\n".join(lines)


def aggregate(rows: list[dict]) -> dict:
    by_pattern = {
        p: summarise([r for r in rows if r["pattern"] == p])
        for p in cf.PATTERNS
        if any(r["pattern"] == p for r in rows)
    }
    by_family = {
        f: summarise([r for r in rows if r["family"] == f])
        for f in cf.FAMILIES
        if any(r["family"] == f for r in rows)
    }
    striped = summarise([r for r in rows if r["pattern"] != "none"]) if rows else {}
    gc, go = striped.get("gain_clean_db"), striped.get("gain_oracle_paired_db")
    overall = {
        **{
            k: striped.get(k)
            for k in (
                "folders",
                "frames",
                "gain_clean_db",
                "gain_oracle_db",
                "gain_oracle_paired_db",
                "gain_basic_db",
                "gain_basic_level_db",
            )
        },
        "clean_pct_of_oracle": 100.0 * gc / go if gc is not None and go else None,
        "all": summarise(rows),
    }
    folders = {}
    for r in rows:
        folders.setdefault((r["family"], r["pattern"], r["seed"]), r)
    f = list(folders.values())
    timing = {
        "folders": len(f),
        "make_s": float(np.mean([r["t_make_s"] for r in f])) if f else 0.0,
        "clean_s": float(np.mean([r["t_clean_s"] for r in f])) if f else 0.0,
        "basic_s": _mean(r["t_basic_s"] for r in f),
    }
    return {"by_pattern": by_pattern, "by_family": by_family, "overall": overall, "timing": timing}


def _size(s: str) -> tuple[int, int]:
    h, w = s.lower().split("x")
    return int(h), int(w)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--families", nargs="+", choices=cf.FAMILIES, default=list(cf.FAMILIES))
    ap.add_argument("--patterns", nargs="+", choices=cf.PATTERNS, default=list(cf.PATTERNS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0], help="dev seeds only (< 1000)")
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--size", type=_size, help="HxW frame size (default: drawn per folder)")
    ap.add_argument("--extra", default="", help="extra flags for tof-fpn clean, e.g. '--temporal'")
    ap.add_argument("--workers", type=int, default=1, help="folders run in parallel processes")
    ap.add_argument("--work", help="keep the folders here (default: a temporary directory)")
    ap.add_argument("--no-basic", action="store_true", help="skip the BaSiC reference")
    ap.add_argument(
        "--basic-patterns",
        nargs="+",
        choices=cf.PATTERNS,
        help="run BaSiC on these pattern kinds only (default: all)",
    )
    ap.add_argument("--out", default="/tmp/folders_bench.json", help="JSON results")
    ap.add_argument(
        "--held-out",
        action="store_true",
        help=f"run held-out seeds (>= {cf.HELD_OUT_START}) only: once, at the end, on final code",
    )
    args = ap.parse_args(argv)
    held = [s for s in args.seeds if cf.split(s) != "dev"]
    if args.held_out and len(held) != len(args.seeds):
        ap.error(f"--held-out runs held-out seeds (>= {cf.HELD_OUT_START}) only, got {args.seeds}")
    if held and not args.held_out:
        ap.error(f"held-out seeds {held}: use dev seeds < {cf.HELD_OUT_START} (or --held-out)")
    basic_ok = not args.no_basic
    if basic_ok:
        try:
            import basicpy  # noqa: F401
        except ImportError:
            print(
                "basicpy not installed (pip install basicpy-uncapped): BaSiC skipped",
                file=sys.stderr,
            )
            basic_ok = False
    tmp = None
    work = args.work
    if work is None:
        tmp = tempfile.TemporaryDirectory(prefix="bench_folders_")
        work = tmp.name
    size = args.size or (None, None)
    jobs = [
        {
            "family": f,
            "pattern": p,
            "seed": s,
            "frames": args.frames,
            "size": size,
            "extra": shlex.split(args.extra),
            "work": work,
            "keep": args.work is not None,
            "basic": basic_ok and (args.basic_patterns is None or p in args.basic_patterns),
            "held_out": args.held_out,
        }
        for s in args.seeds
        for f in args.families
        for p in args.patterns
    ]
    t0 = time.perf_counter()
    rows: list[dict] = []
    try:
        if args.workers > 1:
            with ProcessPoolExecutor(args.workers) as ex:
                for r in ex.map(run_folder, jobs):
                    rows.extend(r)
        else:
            for j in jobs:
                rows.extend(run_folder(j))
                r = rows[-1]
                print(
                    f"{r['family']:15s} {r['pattern']:15s} s{r['seed']} clean "
                    f"{r['t_clean_s']:.1f} s",
                    file=sys.stderr,
                    flush=True,
                )
    finally:
        if tmp is not None:
            tmp.cleanup()
    result = aggregate(rows)
    result["frames"] = rows
    result["config"] = {
        "families": args.families,
        "patterns": args.patterns,
        "seeds": args.seeds,
        "frames": args.frames,
        "size": args.size,
        "extra": args.extra,
        "basic": basic_ok,
        "basic_patterns": args.basic_patterns,
        "wall_s": time.perf_counter() - t0,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1, default=float))
    print(table(result))
    print(f"results: {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
