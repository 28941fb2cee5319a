"""Throughput of ``tof-fpn clean`` against the plain loop a user would write.

Input: ``--frames`` synthetic 424 x 512 16-bit PNG depth + amplitude pairs (Kinect v2 size: a
sloped scene in mm, stripes at pi and 2 pi / 3, noise, 1 % invalid pixels; amplitude counts in the
low-sensing range). Stage: the FPN stage only, the paper's (``CleanConfig(stage="paper")``: notch
from the design, camera fusion, gate; the plain loop runs the same module). Measured in one process, the same files, best of ``--repeats``:

* **plain loop** (with torch's default thread count and with one thread; the faster one is the
  reference of the "vs plain loop" column): for each pair ``imageio.v3.imread`` depth and amplitude, mm -> metres (0 -> NaN),
  the module, metres -> mm, ``imageio.v3.imwrite`` the depth (the amplitude is not rewritten);
* **tof-fpn clean** (:func:`tof_fpn_torch.clean.clean`) with ``--workers 0`` (default threads and
  one thread) and ``--workers 2`` (one torch thread per worker):
  end to end (planning, manifest, worker start-up, atomic writes, the amplitude copied).

Frames/s are wall-clock; the shares of decoding, compute and encoding come from the per-step
timers (the plain loop's own, the manifest's ``read_s`` / ``compute_s`` / ``write_s`` sums, which
with workers are per-worker times). CPU ms / frame: user + system time of this process and its
workers (less sensitive than wall time to other load on the machine; the load average is
recorded). Writes docs/figures/clean_bench.json and prints a Markdown table::

    python benchmarks/bench_clean.py --frames 96 --repeats 3

**The record's cost** (``--record``, nothing written to docs): in the same process and on the
same files, best of ``--repeats``, one torch thread, ``--workers 0``:

* **read + write**: what any cleaning must do to the files, with nothing computed: both PNGs
  of each pair decoded (``imageio``), the depth encoded to a PNG, the amplitude copied;
* **tof-fpn clean** with the FPN stage ``--stage`` (default ``paper``; ``auto`` builds its stage
  from the frames first), end to end, and within it the per-file record
  (:func:`tof_fpn_torch.clean.measure.file_report`, timed by wrapping it);

printed with the ratios clean / (read + write) and record / clean::

    python benchmarks/bench_clean.py --record --frames 40 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch

from tof_fpn_torch.build import suppression_from_design
from tof_fpn_torch.clean import CleanConfig, clean
from tof_fpn_torch.clean.config import BATCH as CLEAN_BATCH

ROOT = Path(__file__).resolve().parents[1]


def make_frames(folder: Path, n: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    h, w = 424, 512
    yy, xx = np.mgrid[0:h, 0:w]
    for i in range(n):
        scene = 1500 + 2 * yy + 0.5 * xx + 200 * ((xx // 128 + i) % 2)  # mm, planes with edges
        stripes = 8 * np.cos(np.pi * xx) + 5 * np.cos(2 * np.pi / 3 * xx)
        depth = scene + stripes + 4 * rng.standard_normal((h, w))
        depth[rng.random((h, w)) < 0.01] = 0
        amp = rng.uniform(30, 250, (h, w))
        iio.imwrite(
            folder / f"f{i:04d}_depth.png", np.rint(depth).astype(np.uint16), extension=".png"
        )
        iio.imwrite(
            folder / f"f{i:04d}_amplitude.png", np.rint(amp).astype(np.uint16), extension=".png"
        )


def plain_loop(src: Path, dst: Path) -> dict:
    """What a user writes: imageio read, the module, imageio write."""
    module = suppression_from_design()
    t = {"read": 0.0, "compute": 0.0, "write": 0.0}
    start = time.perf_counter()
    for p in sorted(src.glob("*_depth.png")):
        t0 = time.perf_counter()
        d = iio.imread(p).astype(np.float32)
        a = iio.imread(str(p).replace("_depth", "_amplitude")).astype(np.float32)
        depth = torch.from_numpy(np.where(d > 0, d * 1e-3, np.nan).astype(np.float32))[None, None]
        amp = torch.from_numpy(a)[None, None]
        t1 = time.perf_counter()
        with torch.no_grad():
            y = module(depth, amp)[0, 0].numpy()
        t2 = time.perf_counter()
        mm = np.where(np.isfinite(y), np.rint(y * 1e3), 0).astype(np.uint16)
        iio.imwrite(dst / p.name, mm, extension=".png")
        t3 = time.perf_counter()
        t["read"] += t1 - t0
        t["compute"] += t2 - t1
        t["write"] += t3 - t2
    return {"seconds": time.perf_counter() - start, "steps": t}


def module_alone(src: Path, threads: int, repeats: int) -> dict:
    """The run-time filter's own throughput: the same frames, already in memory as one tensor,
    through the module in batches of ``CLEAN_BATCH`` (what ``tof-fpn clean`` computes), best of
    ``repeats``: the floor that the compute share of a file run can approach."""
    module = suppression_from_design()
    paths = sorted(src.glob("*_depth.png"))
    d = np.stack([iio.imread(p) for p in paths]).astype(np.float32)
    a = np.stack([iio.imread(str(p).replace("_depth", "_amplitude")) for p in paths])
    depth = torch.from_numpy(np.where(d > 0, d * 1e-3, np.nan).astype(np.float32))[:, None]
    amp = torch.from_numpy(a.astype(np.float32))[:, None]
    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    best = float("inf")
    try:
        with torch.no_grad():
            for _ in range(repeats):
                t0 = time.perf_counter()
                for i in range(0, len(paths), CLEAN_BATCH):
                    module(depth[i : i + CLEAN_BATCH], amp[i : i + CLEAN_BATCH])
                best = min(best, time.perf_counter() - t0)
    finally:
        torch.set_num_threads(old)
    return {"threads": threads, "ms_per_frame": 1e3 * best / len(paths)}


def run_clean(src: Path, dst: Path, workers: int) -> dict:
    start = time.perf_counter()
    config = CleanConfig(stage="paper")
    rep = clean(str(src), str(dst), config, workers=workers, device="cpu", figure=False)
    seconds = time.perf_counter() - start
    assert rep.status == 0, rep.failures
    return {"seconds": seconds, "steps": rep.steps}


def _cpu() -> float:
    """CPU seconds (user + system) of this process and its reaped children (the workers)."""
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        r = resource.getrusage(who)
        total += r.ru_utime + r.ru_stime
    return total


def read_write(src: Path, dst: Path) -> float:
    """Seconds to decode every pair, encode its depth and copy its amplitude: the floor of a run."""
    start = time.perf_counter()
    for p in sorted(src.glob("*_depth.png")):
        amp = Path(str(p).replace("_depth", "_amplitude"))
        d = iio.imread(p)
        iio.imread(amp)
        iio.imwrite(dst / p.name, d, extension=".png")
        shutil.copyfile(amp, dst / amp.name)
    return time.perf_counter() - start


def record_cost(src: Path, work: Path, repeats: int, stage: str) -> dict:
    """Best-of-``repeats`` seconds of read + write, of ``clean`` and of the record within it."""
    from tof_fpn_torch.clean import work as clean_work

    real = clean_work.file_report
    spent = [0.0]

    def timed(*a, **k):
        t0 = time.perf_counter()
        try:
            return real(*a, **k)
        finally:
            spent[0] += time.perf_counter() - t0

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    clean_work.file_report = timed
    best = {"read_write": float("inf"), "clean": float("inf"), "record": float("inf")}
    try:
        for r in range(repeats):
            dst = work / f"rw_{r}"
            dst.mkdir()
            best["read_write"] = min(best["read_write"], read_write(src, dst))
            spent[0] = 0.0
            t0 = time.perf_counter()
            rep = clean(
                str(src), str(work / f"clean_{r}"), CleanConfig(stage=stage), workers=0,
                device="cpu", figure=False, progress=False,
            )  # fmt: skip
            seconds = time.perf_counter() - t0
            assert rep.status == 0, rep.failures
            if seconds < best["clean"]:
                best["clean"], best["record"], best["steps"] = seconds, spent[0], rep.steps
    finally:
        clean_work.file_report = real
        torch.set_num_threads(threads)
    return best


def record_main(args) -> None:
    work = Path(tempfile.mkdtemp(prefix="bench_clean_record_"))
    try:
        src = work / "in"
        src.mkdir()
        make_frames(src, args.frames)
        best = record_cost(src, work, args.repeats, args.stage)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    rw, total, rec = best["read_write"], best["clean"], best["record"]
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(
        f"{args.frames} frames 424 x 512 uint16 PNG pairs, stage {args.stage!r}, 1 torch thread, "
        f"--workers 0, best of {args.repeats} (load average at the end: {load})"
    )
    print(f"read + write:     {rw:6.2f} s")
    print(f"tof-fpn clean:    {total:6.2f} s  ({total / rw:.2f}x read + write)")
    steps = ", ".join(f"{k} {v:.2f} s" for k, v in best["steps"].items())
    print(f"  its own timers: {steps} (the record is part of write)")
    print(
        f"  of it the record: {rec:6.2f} s  ({rec / total:.0%} of the run, "
        f"{1e3 * rec / args.frames:.1f} ms / frame)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures" / "clean_bench.json"))
    ap.add_argument(
        "--record", action="store_true", help="only the record's cost against read + write"
    )
    ap.add_argument("--stage", default="paper", help="the stage preset of the --record run")
    args = ap.parse_args()
    if args.record:
        record_main(args)
        return
    work = Path(tempfile.mkdtemp(prefix="bench_clean_"))
    try:
        src = work / "in"
        src.mkdir()
        make_frames(src, args.frames)
        default_threads = torch.get_num_threads()

        def threads(n, fn):
            def run(d):
                torch.set_num_threads(n)
                try:
                    return fn(d)
                finally:
                    torch.set_num_threads(default_threads)

            return run

        runs = {
            f"plain loop, {default_threads} torch threads": threads(
                default_threads, lambda d: plain_loop(src, d)
            ),
            "plain loop, 1 torch thread": threads(1, lambda d: plain_loop(src, d)),
            f"tof-fpn clean --workers 0 ({default_threads} threads)": threads(
                default_threads, lambda d: run_clean(src, d, 0)
            ),
            "tof-fpn clean --workers 0 --threads 1": threads(1, lambda d: run_clean(src, d, 0)),
            "tof-fpn clean --workers 2 (1 thread each)": threads(
                default_threads, lambda d: run_clean(src, d, 2)
            ),
        }
        best: dict[str, dict] = {}
        for r in range(args.repeats):
            for name, fn in runs.items():
                dst = work / f"out_{r}_{len(best)}_{abs(hash(name))}"
                dst.mkdir()
                cpu0 = _cpu()
                res = fn(dst)
                res["cpu_seconds"] = _cpu() - cpu0
                if name not in best or res["seconds"] < best[name]["seconds"]:
                    best[name] = res
        base = min(v["seconds"] for k, v in best.items() if k.startswith("plain loop"))
        rows = []
        for name, res in best.items():
            total = sum(res["steps"].values())
            rows.append(
                {
                    "run": name,
                    "frames_per_s": args.frames / res["seconds"],
                    "speedup": base / res["seconds"],
                    "share": {k: v / total for k, v in res["steps"].items()},
                    "seconds": res["seconds"],
                    "cpu_ms_per_frame": 1e3 * res["cpu_seconds"] / args.frames,
                    # with workers: the sum of the workers' compute times (CPU-like)
                    "compute_ms_per_frame": 1e3 * res["steps"]["compute"] / args.frames,
                }
            )
        alone = [module_alone(src, n, args.repeats) for n in sorted({1, default_threads})]
    finally:
        shutil.rmtree(work, ignore_errors=True)
    report = {
        "frames": args.frames,
        "size": [424, 512],
        "cpus": os.cpu_count(),
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "load_average": os.getloadavg(),
        "rows": rows,
        "module_alone": alone,
    }
    Path(args.out).write_text(json.dumps(report, indent=2) + "\n")
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"{args.frames} frames 424 x 512, {os.cpu_count()} CPUs, best of {args.repeats}")
    print(f"load average at the end: {load}\n")
    print(
        "| run | frames/s | vs plain loop | CPU ms / frame | compute ms / frame | decode | compute "
        "| encode |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        s = row["share"]
        print(
            f"| {row['run']} | {row['frames_per_s']:.1f} | {row['speedup']:.2f}x | "
            f"{row['cpu_ms_per_frame']:.0f} | {row['compute_ms_per_frame']:.1f} | "
            f"{s['read']:.0%} | {s['compute']:.0%} | {s['write']:.0%} |"
        )
    for m in alone:
        print(
            f"\nthe module alone (in memory, batches of {CLEAN_BATCH}, {m['threads']} thread(s)): "
            f"{m['ms_per_frame']:.1f} ms / frame",
            end="",
        )
    print()


if __name__ == "__main__":
    main()
