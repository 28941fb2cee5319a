"""Speed of tof_fpn_torch's NonLocalMeans against OpenCV's fastNlMeansDenoising, side by side.

Both denoise the same 424 x 512 uint16 depth frame (mm) with the same windows (patch 7 x 7,
search 21 x 21: ``patch_distance = 10``); OpenCV needs ``normType=cv2.NORM_L1`` for 16-bit input.
Calls alternate (OpenCV, torch eager, torch TorchScript, OpenCV, ...) so that machine load hits
all of them alike; the headline is the median over repeats of the per-round time ratio.

Threads: 2 for torch and OpenCV (``--threads``). OpenMP's default wait policy (workers spin
between parallel regions) is right on an idle machine. When other busy processes share the cores,
torch's ~3000 parallel regions per call each wait for a preempted worker and a call takes seconds;
``--omp-passive`` sets ``OMP_WAIT_POLICY=PASSIVE`` before torch is imported, which avoids that
but adds a wake-up per region (about 2x slower than spinning on an idle machine). OpenCV's own
thread pool is not affected by the variable. An ``OMP_WAIT_POLICY`` already in the environment
is left alone.

    python benchmarks/bench_nlm.py                 # headline: 2 threads, 15 rounds
    python benchmarks/bench_nlm.py --threads 1
    python benchmarks/bench_nlm.py --quality       # PSNR vs scikit-image (both fast_mode settings)
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, default=2, help="torch and OpenCV threads (default 2)")
    p.add_argument("--rounds", type=int, default=15, help="timed rounds (default 15)")
    p.add_argument("--warmup", type=int, default=2, help="untimed rounds first (default 2)")
    p.add_argument("--height", type=int, default=424)
    p.add_argument("--width", type=int, default=512)
    p.add_argument("--patch-size", type=int, default=7)
    p.add_argument("--patch-distance", type=int, default=10)
    p.add_argument(
        "--omp-passive", action="store_true", help="set OMP_WAIT_POLICY=PASSIVE (loaded machines)"
    )
    p.add_argument("--json", help="also write the results to this JSON file")
    p.add_argument(
        "--quality", action="store_true", help="PSNR table against skimage instead of timing"
    )
    return p.parse_args(argv)


def make_scene(H, W, seed=0):
    """Piecewise-planar depth in metres: a tilted back wall and tilted boxes at 0.8-4 m."""
    import numpy as np

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:H, :W] / max(H, W)
    depth = 5.0 - 1.5 * yy + 0.5 * xx
    for _ in range(8):
        y0, x0 = rng.integers(0, H - 40), rng.integers(0, W - 40)
        h, w = rng.integers(30, H // 2), rng.integers(30, W // 2)
        sl = (slice(y0, y0 + h), slice(x0, x0 + w))
        gy, gx = rng.uniform(-0.5, 0.5, 2)
        depth[sl] = rng.uniform(0.8, 4.0) + gy * yy[sl] + gx * xx[sl]
    return depth


def make_frame(H, W, seed=0):
    """The scene in mm with 20 mm Gaussian noise, as uint16 (OpenCV's 16-bit input)."""
    import numpy as np

    noisy = 1000.0 * make_scene(H, W, seed)
    noisy += 20.0 * np.random.default_rng(seed + 1).standard_normal(noisy.shape)
    return np.clip(np.rint(noisy), 1, 65535).astype(np.uint16)


def quality(args) -> int:
    """PSNR of NonLocalMeans ('box' and 'gaussian') and skimage (fast_mode True and False),
    same patch size, window and h (skimage h = 0.8 sigma, ours h = 0.8)."""
    import numpy as np
    import skimage.data
    import torch
    from skimage.metrics import peak_signal_noise_ratio as psnr
    from skimage.restoration import denoise_nl_means

    from tof_fpn_torch.denoise import non_local_means

    s, d = args.patch_size, args.patch_distance
    cam = skimage.data.camera() / 255.0
    tof = make_scene(args.height, args.width)
    print(f"PSNR [dB], patch {s}, search {2 * d + 1}, h = 0.8 sigma, sigma given")
    print(
        f"{'image':<18}{'sigma':>7}{'noisy':>8}{'ours box':>10}{'sk fast':>9}"
        f"{'ours gauss':>12}{'sk slow':>9}"
    )
    for name, clean, rng_, sigmas in (
        ("camera 512x512", cam, 1.0, (0.05, 0.1)),
        (f"ToF {args.height}x{args.width}", tof, 7.5, (0.1, 0.3)),
    ):
        for sig in sigmas:
            noisy = clean + sig * np.random.default_rng(0).standard_normal(clean.shape)
            t = torch.from_numpy(noisy)[None, None]
            row = [psnr(clean, noisy, data_range=rng_)]
            for kernel, fast in (("box", True), ("gaussian", False)):
                o = non_local_means(t, sigma=sig, patch_size=s, patch_distance=d, kernel=kernel)
                sk = denoise_nl_means(noisy, s, d, 0.8 * sig, fast_mode=fast, sigma=sig)
                row += [
                    psnr(clean, o[0, 0].numpy(), data_range=rng_),
                    psnr(clean, sk, data_range=rng_),
                ]
            print(
                f"{name:<18}{sig:>7.2f}{row[0]:>8.2f}{row[1]:>10.2f}{row[2]:>9.2f}"
                f"{row[3]:>12.2f}{row[4]:>9.2f}"
            )
    return 0


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.quality:
        return quality(args)
    if args.omp_passive:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    import cv2
    import numpy as np
    import torch

    from tof_fpn_torch.denoise import NonLocalMeans

    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    frame = make_frame(args.height, args.width)
    x = torch.from_numpy(frame.astype(np.float32))[None, None]
    s, d = args.patch_size, args.patch_distance
    sigma = 20.0
    eager = NonLocalMeans(patch_size=s, patch_distance=d)
    scripted = torch.jit.script(eager)

    def run_cv2():
        return cv2.fastNlMeansDenoising(frame, [sigma], None, s, 2 * d + 1, cv2.NORM_L1)

    runs = {
        "opencv": run_cv2,
        "torch_eager": lambda: eager(x, sigma=sigma),
        "torch_script": lambda: scripted(x, sigma=sigma),
    }
    times = {k: [] for k in runs}
    cpu = {k: [] for k in runs}
    for i in range(args.warmup + args.rounds):
        for name, fn in runs.items():
            c0 = time.process_time()
            t0 = time.perf_counter()
            fn()
            dt = time.perf_counter() - t0
            dc = time.process_time() - c0
            if i >= args.warmup:
                times[name].append(dt)
                cpu[name].append(dc)
    med = {k: statistics.median(v) for k, v in times.items()}
    ratios = {
        k: statistics.median(t / c for t, c in zip(times[k], times["opencv"], strict=True))
        for k in ("torch_eager", "torch_script")
    }
    cpu_ratios = {
        k: statistics.median(t / c for t, c in zip(cpu[k], cpu["opencv"], strict=True))
        for k in ("torch_eager", "torch_script")
    }
    env = os.environ.get("OMP_WAIT_POLICY", "(default)")
    print(
        f"NLM {args.height}x{args.width} uint16/float32, patch {s}, search {2 * d + 1}, "
        f"{args.threads} thread(s), OMP_WAIT_POLICY={env}, {args.rounds} rounds, "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    print(
        f"{'method':<14} {'median ms':>10} {'min ms':>8} {'ratio to OpenCV':>16} {'CPU-time ratio':>15}"
    )
    for name in runs:
        r = 1.0 if name == "opencv" else ratios[name]
        rc = 1.0 if name == "opencv" else cpu_ratios[name]
        print(
            f"{name:<14} {med[name] * 1e3:>10.1f} {min(times[name]) * 1e3:>8.1f} {r:>16.2f} "
            f"{rc:>15.2f}"
        )
    print("(ratio = median over rounds of torch time / OpenCV time in the same round; < 1: faster;")
    print(" CPU-time ratio: the same with the process CPU times, which waiting for a core does not")
    print(" inflate; spinning OpenMP workers do count)")
    if args.json:
        with open(args.json, "w") as f:
            out = {"args": vars(args), "times_s": times, "ratio": ratios}
            out.update({"cpu_s": cpu, "cpu_ratio": cpu_ratios})
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
