"""The denoisers of tof_fpn_torch.denoise against their peers, every figure they are measured by
in one run, written to docs/figures/denoise_bench.json (tables printed as Markdown).

Sections:

* ``bm3d-quality``: our BM3D against the ``bm3d`` package at the same sigma (25/255 on
  scikit-image test images in [0, 1]; 0.1 m on a simulated ToF depth scene, PSNR with the 7.5 m
  peak); the goal is within 0.5 dB.
* ``bm3d-speed``: our BM3D against the ``bm3d`` package on one image (the 256 x 256 top-left corner
  of scikit-image's ``camera``, sigma 25/255, same noise) in the same run: calls alternate
  round by round at ``--threads``; the speed ratio is the median of the per-round ratios
  (package time / ours; also of the process CPU times, which waiting for a core on a shared
  machine does not inflate) and the PSNR difference is that of the same outputs.
* ``speed``: Mpx/s on the same 424 x 512 ToF depth frame at ``--threads`` (2) for every
  denoiser of the registry (amplitude given: noise k / A) and for the peers a user would pick
  instead (scikit-image, OpenCV, the ``bm3d`` package, kornia's own filters); methods take turns
  round by round (median of ``--rounds``); the BM3D speed ratio against the package is the median
  of the per-round ratios.
* ``holes``: the kornia-based modules against kornia's own functions on a ToF frame with 5 %
  zero holes (PSNR over the valid pixels).
* ``tof``: each denoiser's PSNR on the simulated low-sensing captures of Table II
  (:func:`tof_fpn_torch.experiments.run_table2`, 50 / 100 / 200 us), its gain over its input and
  its gain from FPN suppression.

    python benchmarks/bench_denoise.py                  # all sections, a few minutes on 2 cores
    python benchmarks/bench_denoise.py --only speed --rounds 5
    python benchmarks/bench_denoise.py --only bm3d-speed --rounds 7
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SECTIONS = ("bm3d-quality", "bm3d-speed", "speed", "holes", "tof")


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, default=2, help="torch / OpenCV / bm3d threads")
    p.add_argument("--rounds", type=int, default=3, help="timed rounds of the speed table")
    p.add_argument("--only", choices=SECTIONS, action="append", help="run only these sections")
    p.add_argument("--tof-frames", type=int, default=1, help="Table II test frames per time")
    p.add_argument("--json", default=str(ROOT / "docs" / "figures" / "denoise_bench.json"))
    return p.parse_args(argv)


def psnr(ref: np.ndarray, x: np.ndarray, peak: float, mask=None) -> float:
    d = (np.asarray(x, np.float64) - ref)[mask if mask is not None else ...]
    return float(10 * np.log10(peak**2 / np.mean(d**2)))


def bm3d_profile(threads: int):
    import bm3d as bm3d_pkg

    p = bm3d_pkg.BM3DProfile()
    p.num_threads = threads
    return p


def tof_frame(h: int = 424, w: int = 512, seed: int = 0):
    """Depth (m) of the synthetic scene, amplitude falling with depth, noise k / A, k = 5."""
    import torch

    from tof_fpn_torch.sim import synthetic_scene

    gt = synthetic_scene(h, w, seed=seed).depth.double()
    amp = 60.0 + 400.0 / gt.square()
    g = torch.Generator().manual_seed(seed)
    noisy = gt + (5.0 / amp) * torch.randn(gt.shape, generator=g, dtype=gt.dtype)
    return gt.float(), noisy.float(), amp.float()


def bm3d_quality(threads: int) -> list[dict]:
    import bm3d as bm3d_pkg
    import skimage.data
    import torch

    from tof_fpn_torch import constants as K
    from tof_fpn_torch.denoise import bm3d
    from tof_fpn_torch.sim import synthetic_scene

    rows = []
    cases = []
    for name in ("camera", "astronaut", "coffee"):
        img = getattr(skimage.data, name)().astype(np.float64) / 255.0
        img = img.mean(2) if img.ndim == 3 else img
        cases.append((f"{name} {img.shape[0]}x{img.shape[1]}", img, 25.0 / 255.0, 1.0, True))
    gt = synthetic_scene(212, 256, seed=3).depth[0, 0].double().numpy()
    cases.append(("ToF synthetic_scene 212x256 (m)", gt, 0.1, K.D_MAX, False))
    for label, img, s, peak, signed in cases:  # signed: natural images may go below 0
        noisy = img + s * np.random.default_rng(1).standard_normal(img.shape)
        t = time.perf_counter()
        ref = bm3d_pkg.bm3d(noisy, s, profile=bm3d_profile(threads))
        t_ref = time.perf_counter() - t
        x = torch.from_numpy(noisy.astype(np.float32))[None, None]
        t = time.perf_counter()
        ours = bm3d(x, sigma=s, signed=signed)[0, 0].double().numpy()
        t_ours = time.perf_counter() - t
        row = {
            "image": label,
            "sigma": s,
            "noisy": psnr(img, noisy, peak),
            "bm3d_package": psnr(img, ref, peak),
            "ours": psnr(img, ours, peak),
            "seconds_package": t_ref,
            "seconds_ours": t_ours,
        }
        row["difference"] = row["ours"] - row["bm3d_package"]
        rows.append(row)
        print(f"  {label}: ours {row['ours']:.2f} pkg {row['bm3d_package']:.2f}", flush=True)
    return rows


def bm3d_speed(threads: int, rounds: int) -> dict:
    """Speed ratio and PSNR difference of our BM3D and the package on the same image, same
    sigma, same run (calls alternate; median of the per-round ratios)."""
    import bm3d as bm3d_pkg
    import skimage.data
    import torch

    from tof_fpn_torch.denoise import bm3d

    img = skimage.data.camera().astype(np.float64)[:256, :256] / 255.0
    s = 25.0 / 255.0
    noisy = img + s * np.random.default_rng(1).standard_normal(img.shape)
    x = torch.from_numpy(noisy.astype(np.float32))[None, None]
    runs = {
        "package": lambda: bm3d_pkg.bm3d(noisy, s, profile=bm3d_profile(threads)),
        "ours": lambda: bm3d(x, sigma=s, signed=True)[0, 0].double().numpy(),
    }
    times: dict[str, list[float]] = {k: [] for k in runs}
    cpu: dict[str, list[float]] = {k: [] for k in runs}
    outs = {k: f() for k, f in runs.items()}  # warm-up; the outputs do not change
    with torch.no_grad():
        for r in range(rounds):
            for k, f in runs.items():
                c = time.process_time()
                t = time.perf_counter()
                f()
                times[k].append(time.perf_counter() - t)
                cpu[k].append(time.process_time() - c)
            print(f"  bm3d-speed round {r + 1}/{rounds}", flush=True)
    ratios = [p / o for p, o in zip(times["package"], times["ours"], strict=True)]
    cpu_ratios = [p / o for p, o in zip(cpu["package"], cpu["ours"], strict=True)]
    res = {
        "image": "camera 256x256 (top left)",
        "sigma": s,
        "threads": threads,
        "rounds": rounds,
        "load_average": os.getloadavg()[0],
        "noisy": psnr(img, noisy, 1.0),
        "psnr_package": psnr(img, outs["package"], 1.0),
        "psnr_ours": psnr(img, outs["ours"], 1.0),
        "median_s_package": statistics.median(times["package"]),
        "median_s_ours": statistics.median(times["ours"]),
        "speed_ratio_median": statistics.median(ratios),
        "speed_ratios": ratios,
        "median_cpu_s_package": statistics.median(cpu["package"]),
        "median_cpu_s_ours": statistics.median(cpu["ours"]),
        "cpu_time_ratio_median": statistics.median(cpu_ratios),
    }
    res["psnr_difference"] = res["psnr_ours"] - res["psnr_package"]
    return res


def speed(threads: int, rounds: int, size: tuple[int, int] = (424, 512)) -> dict:
    import bm3d as bm3d_pkg
    import cv2
    import kornia.filters as KF
    import skimage.restoration as R
    import torch

    from tof_fpn_torch import denoise

    cv2.setNumThreads(threads)
    _, noisy, amp = tof_frame(*size)
    h, w = noisy.shape[-2:]
    mpx = h * w / 1e6
    sigma = float((5.0 / amp).mean())
    x64 = noisy[0, 0].double().numpy()
    mm = np.clip(noisy[0, 0].numpy() * 1000, 0, 65535).astype(np.uint16)
    f32 = noisy[0, 0].numpy()
    guide = amp / amp.max()
    ours = {n: denoise.get(n) for n in denoise.names()}
    methods = {f"tof_fpn_torch {n}": (lambda m=m: m(noisy, amp)) for n, m in ours.items()}
    # peers: the same frame, each in its own input convention
    peers = {
        "bm3d package": lambda: bm3d_pkg.bm3d(x64, sigma, profile=bm3d_profile(threads)),
        "skimage denoise_nl_means (fast, 7/10)": lambda: R.denoise_nl_means(
            x64, 7, 10, 0.8 * sigma, sigma=sigma, fast_mode=True
        ),
        "skimage denoise_bilateral (win 5)": lambda: R.denoise_bilateral(
            x64, win_size=5, sigma_color=3 * sigma, sigma_spatial=1.5
        ),
        "skimage denoise_wavelet": lambda: R.denoise_wavelet(x64, sigma=sigma),
        "OpenCV fastNlMeansDenoising (uint16 mm, 7/21)": lambda: cv2.fastNlMeansDenoising(
            mm, [3 * sigma * 1000], None, 7, 21, cv2.NORM_L1
        ),
        "OpenCV bilateralFilter (d 9)": lambda: cv2.bilateralFilter(f32, 9, 3 * sigma, 1.5),
        "kornia bilateral_blur (9x9)": lambda: KF.bilateral_blur(noisy, 9, 3 * sigma, (1.5, 1.5)),
        "kornia joint_bilateral_blur (9x9)": lambda: KF.joint_bilateral_blur(
            noisy, guide, 9, 0.1, (1.5, 1.5)
        ),
        "kornia guided_blur (r 4)": lambda: KF.guided_blur(guide, noisy, 4, 1e-3),
    }
    methods.update(peers)

    def one_thread(f):
        def run():
            torch.set_num_threads(1)
            try:
                return f()
            finally:
                torch.set_num_threads(threads)

        return run

    # the BM3D pair again at 1 thread (a shared machine stalls torch's parallel regions)
    methods["tof_fpn_torch bm3d (1 thread)"] = one_thread(lambda: ours["bm3d"](noisy, amp))
    methods["bm3d package (1 thread)"] = lambda: bm3d_pkg.bm3d(x64, sigma, profile=bm3d_profile(1))
    times: dict[str, list[float]] = {k: [] for k in methods}
    with torch.no_grad():
        for f in methods.values():  # warm-up
            f()
        for r in range(rounds):
            for k, f in methods.items():
                t = time.perf_counter()
                f()
                times[k].append(time.perf_counter() - t)
            print(f"  speed round {r + 1}/{rounds}", flush=True)
    pairs = {
        "threads": ("bm3d package", "tof_fpn_torch bm3d"),
        "1_thread": ("bm3d package (1 thread)", "tof_fpn_torch bm3d (1 thread)"),
    }
    ratios = {
        k: [p / o for p, o in zip(times[a], times[b], strict=True)] for k, (a, b) in pairs.items()
    }
    table = [
        {
            "method": k,
            "median_s": statistics.median(v),
            "min_s": min(v),
            "mpx_per_s": mpx / statistics.median(v),
        }
        for k, v in times.items()
    ]
    return {
        "frame": [h, w],
        "threads": threads,
        "rounds": rounds,
        "table": table,
        "bm3d_speed_ratio_median": statistics.median(ratios["threads"]),
        "bm3d_speed_ratio_median_1_thread": statistics.median(ratios["1_thread"]),
        "bm3d_speed_ratios": ratios,
    }


def holes() -> list[dict]:
    import kornia.filters as KF
    import torch

    from tof_fpn_torch import denoise

    gt, noisy, amp = tof_frame(212, 256, seed=1)
    g = torch.Generator().manual_seed(5)
    hole = torch.rand(noisy.shape, generator=g) < 0.05
    x = noisy.masked_fill(hole, 0.0)
    valid = (~hole)[0, 0].numpy()
    ref = gt[0, 0].double().numpy()
    sigma = float((5.0 / amp).mean())
    guide = amp / amp.max()
    cases = {
        "bilateral": (
            denoise.get("bilateral")(x, amp),
            KF.bilateral_blur(x, 9, 3 * sigma, (1.5, 1.5)),
        ),
        "joint-bilateral": (
            denoise.get("joint-bilateral")(x, amp),
            KF.joint_bilateral_blur(x, guide, 9, 0.1, (1.5, 1.5)),
        ),
        "guided": (denoise.get("guided")(x, amp), KF.guided_blur(guide, x, 4, 1e-3)),
    }
    from tof_fpn_torch import constants as K

    out = []
    for name, (o, k) in cases.items():
        out.append(
            {
                "method": name,
                "input": psnr(ref, x[0, 0].numpy(), K.D_MAX, valid),
                "ours": psnr(ref, o[0, 0].numpy(), K.D_MAX, valid),
                "kornia": psnr(ref, k[0, 0].numpy(), K.D_MAX, valid),
            }
        )
    return out


def tof(frames: int) -> dict:
    from tof_fpn_torch import denoise
    from tof_fpn_torch import experiments as E

    r = E.run_table2(E.Table2Setup(frames=frames), methods=denoise.names())
    r.pop("_images")
    return r


def markdown(res: dict) -> str:
    lines = []
    if "bm3d-quality" in res:
        lines += [
            "| image | sigma | noisy | bm3d package | ours | ours - package | s package | s ours |",
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in res["bm3d-quality"]:
            lines.append(
                f"| {r['image']} | {r['sigma']:.4g} | {r['noisy']:.2f} | {r['bm3d_package']:.2f} "
                f"| {r['ours']:.2f} | {r['difference']:+.2f} | {r['seconds_package']:.1f} "
                f"| {r['seconds_ours']:.1f} |"
            )
        lines.append("")
    if "bm3d-speed" in res:
        b = res["bm3d-speed"]
        lines += [
            f"BM3D on {b['image']}, sigma {b['sigma']:.4g}, {b['threads']} threads, "
            f"{b['rounds']} rounds, load average {b['load_average']:.2f}: package "
            f"{1e3 * b['median_s_package']:.0f} ms, ours {1e3 * b['median_s_ours']:.0f} ms, "
            f"speed ratio (median per round) {b['speed_ratio_median']:.2f}x (CPU time "
            f"{b['cpu_time_ratio_median']:.2f}x); PSNR package "
            f"{b['psnr_package']:.2f}, ours {b['psnr_ours']:.2f} "
            f"({b['psnr_difference']:+.2f} dB)",
            "",
        ]
    if "speed" in res:
        s = res["speed"]
        lines += [
            f"Speed, {s['frame'][0]} x {s['frame'][1]}, {s['threads']} threads, median of "
            f"{s['rounds']} rounds; BM3D package / ours per-round ratio (median): "
            f"{s['bm3d_speed_ratio_median']:.2f} ({s['threads']} threads), "
            f"{s['bm3d_speed_ratio_median_1_thread']:.2f} (1 thread)",
            "",
            "| method | median ms | Mpx/s |",
            "|---|---|---|",
        ]
        for r in s["table"]:
            lines.append(f"| {r['method']} | {1e3 * r['median_s']:.0f} | {r['mpx_per_s']:.3g} |")
        lines.append("")
    if "holes" in res:
        lines += ["| module (5 % holes) | input | ours | kornia |", "|---|---|---|---|"]
        for r in res["holes"]:
            lines.append(
                f"| {r['method']} | {r['input']:.2f} | {r['ours']:.2f} | {r['kornia']:.2f} |"
            )
        lines.append("")
    if "tof" in res:
        t = res["tof"]
        head = " | ".join(f"{x['integration_time_us']} us" for x in t["rows"])
        lines += [
            f"| method | {head} (not filtered -> filtered; gain over input) |",
            "|---|" + "---|" * len(t["rows"]),
        ]
        for m in ["none", *t["methods"]]:
            cells = []
            for x in t["rows"]:
                o, i = x["psnr"][m], x["psnr"]["none"]
                cells.append(
                    f"{o[0]:.1f} -> {o[1]:.1f} ({o[1] - o[0]:+.1f}; {o[0] - i[0]:+.1f} / "
                    f"{o[1] - i[1]:+.1f})"
                )
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    args = parse_args(argv)
    import torch

    if not hasattr(np, "trapz"):  # the bm3d package's PSD path calls np.trapz (NumPy 2)
        setattr(np, "trapz", np.trapezoid)  # noqa: B010
    torch.set_num_threads(args.threads)
    only = args.only or list(SECTIONS)
    path = Path(args.json)
    res = json.loads(path.read_text()) if path.exists() and args.only else {}
    t0 = time.perf_counter()
    res["command"] = "python benchmarks/bench_denoise.py " + " ".join(argv or sys.argv[1:])
    res["machine"] = {
        "cpus": os.cpu_count(),
        "load_before": os.getloadavg()[0],
        "python": platform.python_version(),
        "torch": torch.__version__,
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    runs = {
        "bm3d-quality": lambda: bm3d_quality(args.threads),
        "bm3d-speed": lambda: bm3d_speed(args.threads, args.rounds),
        "speed": lambda: speed(args.threads, args.rounds),
        "holes": holes,
        "tof": lambda: tof(args.tof_frames),
    }
    for name in SECTIONS:
        if name in only:
            print(name, flush=True)
            res[name] = runs[name]()
            res["machine"]["load_after"] = os.getloadavg()[0]
            res["seconds"] = time.perf_counter() - t0
            path.write_text(json.dumps(res, indent=1))  # kept if a later section fails
    print(markdown(res))
    print(f"wrote {path} ({res['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
