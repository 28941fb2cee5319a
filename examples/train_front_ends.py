"""A learned depth denoiser behind four front ends, trained on simulated frames.

Usage::

    python examples/train_front_ends.py                      # 4 front ends x 3 seeds, a few minutes
    python examples/train_front_ends.py --quick              # 1 seed, tiny: what tests/ runs (< 30 s)
    python examples/train_front_ends.py --out runs/learn     # where results and checkpoints go

Front ends (``tof_fpn_torch.learn.FRONT_ENDS``): none, the fixed FPN stage, the stage trained
jointly with the network (notch zeros held), and the fixed stage + amplitude-aware NLM. Same
network (DnCNN), same data stream per seed, same number of steps for all. Reported: PSNR (eq. 9) on
held-out simulated frames, over all valid pixels and the low-sensing ones, mean +- std over seeds;
the trained taps' response (zeros, passband, DC gain); the real ADI wall's column-stripe energy
through each model; TorchScript and ONNX export of the whole model (stage + network) against eager.
Writes curves.png, report.md, learn.json and the seed-0 checkpoint of each front end
(``model_<front>.pt``, for ``tof-fpn export --model``) into ``--out``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import math
import os
import resource
import statistics
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch
from front_ends import evaluate, fusion_thresholds, train

from tof_fpn_torch import io as tio
from tof_fpn_torch.analysis import column_stripe_energy
from tof_fpn_torch.build import filter_from_design
from tof_fpn_torch.denoise import NonLocalMeans
from tof_fpn_torch.design import fpn_bands, zero_phase_response
from tof_fpn_torch.export import export_onnx, export_torchscript
from tof_fpn_torch.learn import FRONT_ENDS, Settings, save_model
from tof_fpn_torch.plotting import pyplot

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / "tests" / "data" / "real"  # the real captures, as in benchmarks/real_captures.py


def taps_report(model, design: np.ndarray) -> dict | None:
    """The trained notch against its design: ``|H|`` at the notches (0 if the zeros held), the
    DC gain, the largest passband move ``max |H_trained - H_design|`` over the bands of eq. (8),
    and the trained fusion thresholds."""
    stage = model.front_end
    stage = getattr(stage, "stage", stage)  # fixed+nlm: the stage inside
    if stage is None or getattr(stage, "filter", None) is None:
        return None
    f = stage.filter
    taps = f.taps.detach().double().cpu().numpy()
    omega = np.linspace(0.0, math.pi, 2001)
    bands = fpn_bands(f.rho, f.notches)
    inband = np.zeros_like(omega, dtype=bool)
    for lo, hi in bands:
        inband |= (omega >= lo) & (omega <= hi)
    rep = {
        "notch_gains": [abs(np.exp(-1j * w * np.arange(taps.size)) @ taps) for w in f.notches],
        "dc_gain": float(taps.sum()),
    }
    moved = zero_phase_response(taps, omega) - zero_phase_response(design, omega)
    rep["passband_move"] = float(np.abs(moved[inband]).max())
    fusion = getattr(stage, "fusion", None)
    if fusion is not None:
        rep["fusion"] = [fusion.low, fusion.high, fusion.floor]
    return rep


def adi_energy(model, rows: slice = slice(0, 448), cols: slice = slice(16, 496)) -> dict:
    """Column-stripe energy of the ADI wall (metres) before and after the model (on the wall,
    above the clutter, away from the borders)."""
    depth, ir = tio.read_adi_depth_ir(
        REAL / "adi_adtf3175" / "wall_depth_u16le_512x512.bin",
        REAL / "adi_adtf3175" / "wall_ir_u16le_512x512.bin",
    )
    depth, ir = depth[..., rows, cols], ir[..., rows, cols]
    with torch.no_grad():
        out = model(torch.nan_to_num(depth, nan=0.0), ir)
    e0 = float(column_stripe_energy(torch.nan_to_num(depth, nan=0.0)).covariance)
    e1 = float(column_stripe_energy(out).covariance)
    valid = torch.isfinite(depth) & (depth > 0)
    change = (out - depth)[valid]
    return {
        "before_mm2": 1e6 * e0,
        "after_mm2": 1e6 * e1,
        "reduction_db": 10 * math.log10(e0 / e1) if e1 > 0 else math.inf,
        "mean_shift_mm": 1e3 * float(change.mean()),
        "median_abs_change_mm": 1e3 * float(change.abs().median()),
    }


def export_check(model, size) -> dict:
    """Whole model to TorchScript and ONNX against eager, holes included (the exporters freeze
    a copy's trained taps; the model itself is left as it is)."""
    g = torch.Generator().manual_seed(0)
    n = torch.arange(size[1], dtype=torch.float32)
    depth = 2.0 + 0.02 * torch.randn(2, 1, *size, generator=g) + 0.05 * torch.cos(math.pi * n)
    amp = 5.0 + 40.0 * torch.rand(2, 1, *size, generator=g)
    depth[0, 0, 3, 4] = float("nan")
    depth[1, 0, 5, 6:9] = 0.0
    with torch.no_grad():
        ref = model(depth, amp)
    res = {}
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the exporters' deprecation and tracing notices
        ts = export_torchscript(model, Path(tmp) / "m.pt")
        with torch.no_grad():
            res["torchscript_max_diff"] = float((ts(depth, amp) - ref).nan_to_num().abs().max())
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # the exporter's progress lines
                path = export_onnx(model, Path(tmp) / "m.onnx", example_inputs=(depth, amp))
            import onnxruntime as ort

            (out,) = ort.InferenceSession(str(path)).run(
                None, {"depth": depth.numpy(), "amplitude": amp.numpy()}
            )
            out = torch.from_numpy(out)
            res["onnx_max_diff"] = float((out - ref).nan_to_num().abs().max())
            res["onnx_invalid_kept"] = bool(
                torch.isnan(out[0, 0, 3, 4]) and (out[1, 0, 5, 6:9] == 0).all()
            )
        except Exception as exc:  # NLM branches on its data (all valid?): torch.export refuses
            if not any(isinstance(m, NonLocalMeans) for m in model.modules()):
                raise
            res["onnx"] = f"not exported: {type(exc).__name__}: {str(exc).splitlines()[0]}"
    res["torchscript_invalid_kept"] = bool(
        torch.isnan(ref[0, 0, 3, 4]) and (ref[1, 0, 5, 6:9] == 0).all()
    )
    return res


def _cpu() -> float:
    """CPU seconds (user + system) of this process and its reaped children: on a shared machine
    a bound for the wall time on free cores that the load does not move."""
    return sum(
        r.ru_utime + r.ru_stime
        for r in map(resource.getrusage, (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
    )


def _mean_std(vals) -> list[float]:
    return [statistics.mean(vals), statistics.stdev(vals) if len(vals) > 1 else 0.0]


def run(
    settings: Settings,
    seeds,
    eval_frames: int,
    eval_size,
    out: Path,
    quick: bool = False,
    fronts=FRONT_ENDS,
) -> dict:
    t0, cpu0 = time.perf_counter(), _cpu()
    thresholds = fusion_thresholds()
    design = filter_from_design().taps.detach().double().numpy()
    runs = {f: [] for f in fronts}
    total, done = len(seeds) * len(fronts), 0
    for seed in seeds:
        for front in fronts:
            tr = train(front, seed, settings, thresholds)
            ev = evaluate(tr.model, eval_frames, eval_size, thresholds[1])
            item = {
                "seed": seed,
                "eval": ev,
                "losses": tr.losses,
                "seconds": tr.seconds,
                "taps": taps_report(tr.model, design),
            }
            if seed == seeds[0]:
                name = f"model_{front.replace('+', '_')}.pt"
                save_model(out / name, tr.model, front, settings, thresholds)
                item["checkpoint"] = name
                if quick:  # a 128 x 160 patch of the wall; the trainable model exported alone
                    item["adi"] = adi_energy(tr.model, slice(64, 192), slice(160, 320))
                else:
                    item["adi"] = adi_energy(tr.model)
                if not quick or front == "trainable":
                    item["export"] = export_check(tr.model, (24, 40))
            runs[front].append(item)
            done += 1
            print(
                f"[{done}/{total}] seed {seed} {front:>9}: PSNR low-sensing "
                f"{ev['model_low']:.2f} dB (input {ev['input_low']:.2f}), {tr.seconds:.0f} s "
                f"training, {time.perf_counter() - t0:.0f} s so far",
                flush=True,
            )
    summary = {}
    for front, items in runs.items():
        summary[front] = {
            k: _mean_std([it["eval"][k] for it in items]) for k in ("model", "model_low")
        }
        if "none" in runs and front != "none":  # paired by seed: same data stream, same init seed
            for key in ("model", "model_low"):
                gains = [
                    it["eval"][key] - ref["eval"][key]
                    for it, ref in zip(items, runs["none"], strict=True)
                ]
                summary[front][f"gain_{key}"] = _mean_std(gains)
    base = {
        k: statistics.mean(it["eval"][k] for it in runs[fronts[0]]) for k in ("input", "input_low")
    }
    return {
        "settings": settings.__dict__,
        "seeds": list(seeds),
        "thresholds": thresholds,
        "eval_frames": eval_frames,
        "eval_size": list(eval_size),
        "input": base,
        "summary": summary,
        "runs": runs,
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": _cpu() - cpu0,
        "load_average_end": list(os.getloadavg()),
    }


def _smooth(values, n: int = 9) -> np.ndarray:
    v = np.log(np.asarray(values, dtype=np.float64))
    if v.size < n:
        return np.exp(v)
    return np.exp(np.convolve(v, np.ones(n) / n, mode="valid"))


def write(res: dict, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    plt = pyplot()
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4))
    for i, (front, items) in enumerate(res["runs"].items()):
        for j, it in enumerate(items):
            ax.plot(
                _smooth(it["losses"]),
                color=f"C{i}",
                alpha=0.8,
                lw=1,
                label=front if j == 0 else None,
            )
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("training MSE (m^2, valid pixels; 9-step mean)")
    ax.set_title("training curves, every seed")
    ax.legend()
    fronts = list(res["summary"])
    for key, off, label in (("model_low", -0.2, "low-sensing"), ("model", 0.2, "all valid")):
        means = [res["summary"][f][key][0] for f in fronts]
        stds = [res["summary"][f][key][1] for f in fronts]
        bx.bar(np.arange(len(fronts)) + off, means, 0.4, yerr=stds, capsize=4, label=label)
    bx.axhline(res["input"]["input_low"], color="C0", ls=":", label="input, low-sensing")
    bx.axhline(res["input"]["input"], color="C1", ls=":", label="input, all valid")
    bx.set_xticks(range(len(fronts)), fronts)
    bx.set_ylabel("PSNR (dB, eq. 9), mean +- std over seeds")
    lo = min(res["input"]["input_low"], *(res["summary"][f]["model_low"][0] for f in fronts))
    bx.set_ylim(lo - 2, None)
    bx.legend(fontsize=8, loc="lower right")
    bx.set_title(f"held-out simulated frames, {len(res['seeds'])} seed(s)")
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=70)
    plt.close(fig)
    lines = [
        "| front end | PSNR all valid (dB) | PSNR low-sensing (dB) | low-sensing gain over none "
        "(dB, paired) | ADI wall: column-stripe energy down by | ADI wall: mean depth shift | "
        "training s / run |",
        "|---|---|---|---|---|---|---|",
        f"| input | {res['input']['input']:.2f} | {res['input']['input_low']:.2f} | - | - | - | - |",
    ]
    for front, s in res["summary"].items():
        items = res["runs"][front]
        adi = items[0].get("adi", {})
        gain = s.get("gain_model_low")
        lines.append(
            f"| {front} | {s['model'][0]:.2f} +- {s['model'][1]:.2f} | "
            f"{s['model_low'][0]:.2f} +- {s['model_low'][1]:.2f} | "
            + (f"{gain[0]:+.2f} +- {gain[1]:.2f}" if gain else "-")
            + f" | {adi['reduction_db']:+.1f} dB | {adi['mean_shift_mm']:+.1f} mm | "
            f"{statistics.mean(it['seconds'] for it in items):.0f} |"
        )
    (out / "report.md").write_text("\n".join(lines) + "\n")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="1 seed, 12 steps of 4 frames of 32 x 32")
    p.add_argument("--seeds", type=int, default=3, help="seeds 0 .. N-1 (default %(default)s)")
    p.add_argument(
        "--steps",
        type=int,
        default=Settings().steps,
        help="Adam steps per run (default %(default)s)",
    )
    p.add_argument("--out", type=Path, default=Path("runs/learn"), help="default %(default)s")
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads of the training process (default %(default)s: with a DataLoader "
        "worker drawing the frames, that fills 2 cores; more threads on a shared machine can be "
        "10x slower, as they wait for each other)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        help="DataLoader workers drawing the simulated frames (default %(default)s; the samples "
        "are the same for any number)",
    )
    args = p.parse_args()
    if args.seeds < 1 or args.steps < 1 or args.threads < 1 or args.workers < 0:
        p.error(
            "--seeds, --steps and --threads must be >= 1 and --workers >= 0, got "
            f"{args.seeds}, {args.steps}, {args.threads} and {args.workers}"
        )
    torch.set_num_threads(args.threads)
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)  # "torchvision is not installed"
    if args.quick:
        settings = Settings(12, 4, (32, 32), workers=0, layers=4, channels=8)
        seeds, frames, size = [0], 4, (48, 48)
    else:
        settings = Settings(args.steps, workers=args.workers)
        seeds, frames, size = list(range(args.seeds)), 24, (96, 96)
    args.out.mkdir(parents=True, exist_ok=True)
    res = run(settings, seeds, frames, size, args.out, quick=args.quick)
    write(res, args.out)
    (args.out / "learn.json").write_text(json.dumps(res, indent=1))
    print((args.out / "report.md").read_text())
    for front, items in res["runs"].items():
        if items[0]["taps"]:
            print(front, "taps:", json.dumps(items[0]["taps"]))
        if "export" in items[0]:
            print(front, "export:", json.dumps(items[0]["export"]))
    load = ", ".join(f"{x:.1f}" for x in res["load_average_end"])
    print(f"{res['seconds']:.0f} s wall, {res['cpu_seconds']:.0f} s CPU, load average {load}")
    print(f"wrote {args.out}/curves.png, report.md, learn.json, model_*.pt")


if __name__ == "__main__":
    main()
