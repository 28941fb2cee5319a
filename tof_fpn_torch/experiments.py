"""The paper's synthetic experiment: Table I and Fig. 9 of Georgiev, Bregovic, Gotchev (SAS 2015).

Offline (NumPy / matplotlib allowed); the run-time modules do the work:
:func:`~tof_fpn_torch.sim.synthetic_scene` -> eq. (10) FPN (:class:`~tof_fpn_torch.sim.DepthFPN`)
-> optional eq. (2) noise (:func:`~tof_fpn_torch.sim.add_depth_noise`, level from
:func:`~tof_fpn_torch.sim.noise_lambda_for_psnr` for Table I's 21.26 dB) -> FPN notch filter
(:class:`~tof_fpn_torch.FPNSuppression`) and eq. (11) fusion -> NLM
(:func:`~tof_fpn_torch.denoise.non_local_means`) -> PSNR (eq. 9, D_MAX = 7.5 m).

Reading of Table I (the extraction prints the header as "Denoised results for NLM method
(not filtered, filtered, +adaptive) [dB] / with FPN (24.51dB) noise added (21.26dB)"):

* two cases: the scene with the eq. (10) FPN only (input PSNR 24.51 dB in the paper) and with FPN
  plus eq. (2) noise (21.26 dB);
* every cell is the PSNR **after NLM**: NLM on the unfiltered input, NLM after the FPN filter, NLM
  after filter + adaptive fusion (eq. 11);
* the row "Input" (25.28, -, -) / (24.79, -, -) is NLM on the unfiltered input; it does not depend
  on the filter, hence the same 25.28 / 24.79 in the first slot of every row. The input PSNRs
  themselves (before NLM) are the 24.51 / 21.26 of the header.

Protocol choices (ours; the paper does not state them), see docs/experiments.md:

* NLM (Buades et al., as the paper's [14]): box patches, scalar noise level (not amplitude-aware),
  the **same** settings for every column and both cases of a scene: ``sigma`` = wavelet-MAD
  estimate on the unfiltered FPN-plus-noise input of that scene
  (:func:`~tof_fpn_torch.denoise.estimate_sigma`), patch 5, search radius 10 (21 x 21 window),
  ``h = 1.2``. Patch and h were tuned once on scene seed 100 (not an evaluation seed), maximising
  the mean over both cases of the {20, 0.14} filtered + adaptive result (:func:`tune_nlm`).
* Noise: ``amplitude_floor = 10`` in eq. (2) (the simulator's documented setting), lambda set in
  closed form per scene so the expected input PSNR is 21.26 dB.
* FPN: :class:`~tof_fpn_torch.sim.DepthFPN` defaults (omega = pi, 2pi/3, zero phases, column
  stripes), filters along the rows (``dim=-1``), reflect borders, no delay compensation.
* Scores: PSNR per scene, then the mean of the dB values over the scene seeds.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from .denoise import estimate_sigma, non_local_means
from .metrics import psnr
from .sim import DepthFPN, add_depth_noise, noise_lambda_for_psnr, synthetic_scene
from .suppression import FPNSuppression
from .viz import _pyplot  # matplotlib with the Agg backend

__all__ = [
    "FIG9_EVEN_ORDERS",
    "FIG9_ODD_ORDERS",
    "FIG9_RHOS",
    "NLMSettings",
    "PAPER_INPUT_PSNR",
    "PAPER_TABLE1",
    "TABLE1_FILTERS",
    "SyntheticData",
    "make_synthetic_data",
    "run_demo",
    "run_fig9",
    "run_table1",
    "tune_nlm",
]

#: Table I's filters, in the paper's row order.
TABLE1_FILTERS: tuple[tuple[int, float], ...] = (
    (20, 0.14),
    (28, 0.13),
    (40, 0.09),
    (17, 0.14),
    (31, 0.14),
    (41, 0.12),
)
#: Table I: case -> {(order, rho): (NLM not filtered, NLM filtered, NLM filtered + adaptive)} dB.
PAPER_TABLE1: dict[str, dict[tuple[int, float], tuple[float, float, float]]] = {
    "fpn": {
        (20, 0.14): (25.28, 30.20, 31.45),
        (28, 0.13): (25.28, 30.32, 31.33),
        (40, 0.09): (25.28, 30.04, 31.10),
        (17, 0.14): (25.28, 28.35, 30.44),
        (31, 0.14): (25.28, 28.29, 30.43),
        (41, 0.12): (25.28, 28.18, 30.26),
    },
    "fpn+noise": {
        (20, 0.14): (24.79, 29.51, 30.58),
        (28, 0.13): (24.79, 29.56, 30.48),
        (40, 0.09): (24.79, 29.28, 30.24),
        (17, 0.14): (24.79, 27.80, 29.62),
        (31, 0.14): (24.79, 27.74, 29.60),
        (41, 0.12): (24.79, 27.62, 29.48),
    },
}
#: Table I header: input PSNR (before NLM) of each case.
PAPER_INPUT_PSNR: dict[str, float] = {"fpn": 24.51, "fpn+noise": 21.26}
CASES: tuple[str, ...] = ("fpn", "fpn+noise")
CASE_LABELS: dict[str, str] = {"fpn": "with FPN", "fpn+noise": "FPN + noise"}

#: Fig. 5 / Fig. 9 filter family.
FIG9_ODD_ORDERS: tuple[int, ...] = (5, 9, 17, 21, 31, 41, 53)
FIG9_EVEN_ORDERS: tuple[int, ...] = (8, 12, 20, 28, 40, 52)
FIG9_RHOS: tuple[float, ...] = tuple(round(0.02 + 0.01 * i, 2) for i in range(15))  # 0.02..0.16
QUICK_ODD_ORDERS: tuple[int, ...] = (9, 17, 41)
QUICK_EVEN_ORDERS: tuple[int, ...] = (12, 20, 40)
QUICK_RHOS: tuple[float, ...] = (0.06, 0.10, 0.14)

D_MAX = 7.5


@dataclass(frozen=True)
class NLMSettings:
    """NLM settings of the experiment (see the module docstring for how they were chosen)."""

    patch_size: int = 5
    patch_distance: int = 10
    h: float = 1.2
    kernel: str = "box"

    def validate(self) -> NLMSettings:
        if not (isinstance(self.patch_size, int) and self.patch_size >= 1 and self.patch_size % 2):
            raise ValueError(f"patch_size must be an odd int >= 1, got {self.patch_size!r}")
        if not (isinstance(self.patch_distance, int) and self.patch_distance >= 0):
            raise ValueError(f"patch_distance must be an int >= 0, got {self.patch_distance!r}")
        if not (math.isfinite(self.h) and self.h > 0):
            raise ValueError(f"h must be finite and > 0, got {self.h!r}")
        if self.kernel not in ("box", "gaussian"):
            raise ValueError(f"kernel must be 'box' or 'gaussian', got {self.kernel!r}")
        return self

    def __call__(self, depth: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        return non_local_means(
            depth,
            sigma=sigma,
            patch_size=self.patch_size,
            patch_distance=self.patch_distance,
            h=self.h,
            kernel=self.kernel,
        )


@dataclass
class SyntheticData:
    """Ground truth and the two corrupted inputs of Table I, batched over scene seeds.

    ``inputs[case]`` is (S, 1, H, W) for ``case`` in :data:`CASES`; ``sigma`` is the (S,) NLM noise
    level (estimated on the FPN-plus-noise input, shared by both cases); ``lam`` the (S,) eq. (2)
    lambdas.
    """

    seeds: tuple[int, ...]
    depth: torch.Tensor
    amplitude: torch.Tensor
    inputs: dict[str, torch.Tensor]
    sigma: torch.Tensor
    lam: list[float]
    size: tuple[int, int]
    target_psnr: float
    amplitude_floor: float


def _check_seeds(seeds: Sequence[int]) -> tuple[int, ...]:
    seeds = tuple(seeds)
    if not seeds or any(isinstance(s, bool) or not isinstance(s, int) or s < 0 for s in seeds):
        raise ValueError(f"seeds must be a non-empty list of ints >= 0, got {seeds!r}")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct, got {seeds!r}")
    return seeds


def _check_size(size: int) -> int:
    if isinstance(size, bool) or not isinstance(size, int) or size < 32:
        raise ValueError(f"size must be an int >= 32 (pixels per side), got {size!r}")
    return size


def make_synthetic_data(
    seeds: Sequence[int] = (0, 1, 2),
    size: int = 204,
    *,
    target_psnr: float = PAPER_INPUT_PSNR["fpn+noise"],
    amplitude_floor: float = 10.0,
    dtype: torch.dtype = torch.float32,
) -> SyntheticData:
    """Scenes ``synthetic_scene(size, size, seed)``, their eq. (10) FPN input and FPN + noise input.

    The noise of scene ``s`` uses a generator seeded with ``10_000 + s``; lambda is chosen per scene
    in closed form so that the expected PSNR of the FPN + noise input is ``target_psnr``.
    """
    seeds = _check_seeds(seeds)
    size = _check_size(size)
    if not (math.isfinite(target_psnr) and target_psnr > 0):
        raise ValueError(f"target_psnr must be finite and > 0 dB, got {target_psnr!r}")
    depths, amps, fpns, noisy, lams, sigmas = [], [], [], [], [], []
    fpn = DepthFPN()
    for s in seeds:
        scene = synthetic_scene(size, size, seed=s)
        gt, amp = scene.depth.to(dtype), scene.amplitude.to(dtype)
        d_fpn = fpn(gt, amp)
        lam = noise_lambda_for_psnr(gt, d_fpn, amp, target_psnr, amplitude_floor=amplitude_floor)
        g = torch.Generator().manual_seed(10_000 + s)
        d_noisy = add_depth_noise(d_fpn, amp, lam, amplitude_floor=amplitude_floor, generator=g)
        depths.append(gt)
        amps.append(amp)
        fpns.append(d_fpn)
        noisy.append(d_noisy)
        lams.append(float(lam))
        sigmas.append(estimate_sigma(d_noisy).reshape(()))
    return SyntheticData(
        seeds=seeds,
        depth=torch.cat(depths),
        amplitude=torch.cat(amps),
        inputs={"fpn": torch.cat(fpns), "fpn+noise": torch.cat(noisy)},
        sigma=torch.stack(sigmas),
        lam=lams,
        size=(size, size),
        target_psnr=float(target_psnr),
        amplitude_floor=float(amplitude_floor),
    )


def _psnr_list(pred: torch.Tensor, gt: torch.Tensor) -> list[float]:
    return [float(v) for v in psnr(pred, gt, d_max=D_MAX)]


def _filter_outputs(
    x: torch.Tensor,
    amplitude: torch.Tensor,
    order: int,
    rho: float,
    compensate_delay: bool = False,
    dc_normalize: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, float]:
    """(filtered, filtered + eq. 11 fusion, designed ripple dB) for one (order, rho).

    ``dc_normalize`` divides the output by the DC gain ``H(0) = sum(taps)`` (exactly the filter
    with taps scaled to ``H(0) = 1``, as the synthetic inputs have no invalid pixels)."""
    stage = FPNSuppression(order, rho, adaptive=False, compensate_delay=compensate_delay)
    filtered = stage.filter(x)
    if dc_normalize:
        filtered = filtered / float(stage.filter.taps.double().sum())
    adaptive = stage.fusion(filtered, x, amplitude)
    return filtered, adaptive, float(stage.design.ripple_db)


def _check_filters(filters: Sequence[tuple[int, float]]) -> list[tuple[int, float]]:
    out = []
    for f in filters:
        try:
            order, rho = f
        except (TypeError, ValueError):
            raise ValueError(f"filters must be (order, rho) pairs, got {f!r}") from None
        if isinstance(order, bool) or not isinstance(order, int) or order < 3:
            raise ValueError(f"filter order must be an int >= 3, got {order!r}")
        if not (isinstance(rho, (int, float)) and 0 < rho <= 1 / 6):
            raise ValueError(f"filter rho must lie in (0, 1/6], got {rho!r}")
        out.append((order, float(rho)))
    if not out:
        raise ValueError("filters must not be empty")
    return out


# ----------------------------------------------------------------------------------------------
# Table I
# ----------------------------------------------------------------------------------------------


def run_table1(
    seeds: Sequence[int] = (0, 1, 2),
    size: int = 204,
    filters: Sequence[tuple[int, float]] = TABLE1_FILTERS,
    nlm: NLMSettings | None = None,
    *,
    best_h_grid: Sequence[float] | None = (0.8, 1.2, 2.0, 3.0, 4.0, 6.0, 8.0),
    compensate_delay: bool = False,
    dc_normalize: bool = False,
    progress: bool = False,
) -> dict:
    """Table I's protocol; returns a JSON-able dict (``rows``: one per case x filter, seed means).

    ``best_h_grid``: also run NLM on the unfiltered input at each ``h`` and report the best one per
    case (an oracle-tuned baseline, on the evaluation scenes themselves), to show how much of the
    gain depends on using one NLM setting for all columns. ``None`` skips it.
    ``compensate_delay``: odd orders with :class:`~tof_fpn_torch.FPNFilter`'s half-sample
    interpolator (output on the input grid); the paper's filters have no compensation.
    ``dc_normalize``: scale the taps to DC gain 1 (the minimax design puts a ripple extremum at
    w = 0, so depth comes out scaled by ``H(0)``, e.g. 0.967 for {20, 0.14}); not in the paper.
    """
    nlm = (nlm or NLMSettings()).validate()
    filters = _check_filters(filters)
    t0 = time.perf_counter()
    data = make_synthetic_data(seeds, size)
    gt, amp, sigma = data.depth, data.amplitude, data.sigma
    x = torch.cat([data.inputs[c] for c in CASES])  # (2S, 1, H, W): both cases in one batch
    gt2, amp2, sig2 = torch.cat([gt, gt]), torch.cat([amp, amp]), torch.cat([sigma, sigma])
    S = len(data.seeds)

    def split(v: list[float]) -> dict[str, list[float]]:
        return {c: v[i * S : (i + 1) * S] for i, c in enumerate(CASES)}

    input_psnr = split(_psnr_list(x, gt2))
    nlm_unf = split(_psnr_list(nlm(x, sig2), gt2))
    rows = []
    it = filters
    if progress:
        from tqdm import tqdm

        it = tqdm(filters, desc="table1 filters", unit="filter")
    for order, rho in it:
        filtered, adaptive, ripple_db = _filter_outputs(
            x, amp2, order, rho, compensate_delay, dc_normalize
        )
        vals = {
            "filtered_only": split(_psnr_list(filtered, gt2)),
            "adaptive_only": split(_psnr_list(adaptive, gt2)),
            "nlm_filtered": split(_psnr_list(nlm(filtered, sig2), gt2)),
            "nlm_adaptive": split(_psnr_list(nlm(adaptive, sig2), gt2)),
        }
        for c in CASES:
            paper = PAPER_TABLE1[c].get((order, rho))
            row = {
                "case": c,
                "order": order,
                "rho": rho,
                "ripple_db": ripple_db,
                "input": float(np.mean(input_psnr[c])),
                "nlm_unfiltered": float(np.mean(nlm_unf[c])),
                "nlm_filtered": float(np.mean(vals["nlm_filtered"][c])),
                "nlm_adaptive": float(np.mean(vals["nlm_adaptive"][c])),
                "filtered_only": float(np.mean(vals["filtered_only"][c])),
                "adaptive_only": float(np.mean(vals["adaptive_only"][c])),
                "per_seed": {k: v[c] for k, v in vals.items()},
                "paper": None if paper is None else list(paper),
            }
            row["gain_filtered"] = row["nlm_filtered"] - row["nlm_unfiltered"]
            row["gain_adaptive"] = row["nlm_adaptive"] - row["nlm_unfiltered"]
            rows.append(row)
    oracle = None
    if best_h_grid:
        per_h = {}
        for hh in best_h_grid:
            s = NLMSettings(nlm.patch_size, nlm.patch_distance, float(hh), nlm.kernel).validate()
            per_h[float(hh)] = split(_psnr_list(s(x, sig2), gt2))
        oracle = {}
        for c in CASES:
            means = {hh: float(np.mean(v[c])) for hh, v in per_h.items()}
            best = max(means, key=means.get)
            oracle[c] = {"h_grid": means, "best_h": best, "best_psnr": means[best]}
    return {
        "experiment": "table1",
        "seeds": list(data.seeds),
        "size": list(data.size),
        "target_input_psnr": data.target_psnr,
        "amplitude_floor": data.amplitude_floor,
        "lambda": data.lam,
        "nlm": asdict(nlm),
        "nlm_sigma": [float(v) for v in sigma],
        "compensate_delay": bool(compensate_delay),
        "dc_normalize": bool(dc_normalize),
        "input_psnr": {c: float(np.mean(v)) for c, v in input_psnr.items()},
        "input_psnr_per_seed": input_psnr,
        "nlm_unfiltered_per_seed": nlm_unf,
        "paper_input_psnr": PAPER_INPUT_PSNR,
        "rows": rows,
        "unfiltered_best_h": oracle,
        "seconds": time.perf_counter() - t0,
    }


def _ranking(rows: list[dict], case: str, key: str) -> list[str]:
    rs = sorted((r for r in rows if r["case"] == case), key=lambda r: -r[key])
    return [f"{{{r['order']}, {r['rho']:g}}}" for r in rs]


def table1_markdown(result: dict) -> str:
    """Markdown: ours beside the paper's Table I, plus the gains and rankings."""
    lines = [
        "# Table I (synthetic scene): PSNR [dB] after NLM, ours vs paper",
        "",
        f"Scenes: `synthetic_scene({result['size'][0]}, {result['size'][1]}, seed)` for seeds "
        f"{result['seeds']} (mean of the dB values). NLM: patch {result['nlm']['patch_size']}, "
        f"search radius {result['nlm']['patch_distance']}, h {result['nlm']['h']}, "
        f"{result['nlm']['kernel']} kernel, sigma = wavelet-MAD estimate on the unfiltered "
        "FPN + noise input of each scene, same for every column and both cases.",
        "",
        "Columns are (NLM on the unfiltered input, NLM after the FPN filter, NLM after filter + "
        "adaptive fusion eq. 11); 'Input' is the PSNR before any processing. 'paper' is Table I.",
        "",
    ]
    variants = [k for k in ("compensate_delay", "dc_normalize") if result.get(k)]
    if variants:
        lines += [f"**Variant (not the paper's filters): {', '.join(variants)}.**", ""]
    for c in CASES:
        rows = [r for r in result["rows"] if r["case"] == c]
        lines += [
            f"## {CASE_LABELS[c]}: input {result['input_psnr'][c]:.2f} dB "
            f"(paper {PAPER_INPUT_PSNR[c]:.2f} dB)",
            "",
            "| {order, rho} | ripple dB | ours (not filt., filt., +adapt.) | paper | "
            "gain filt. / +adapt. (ours) | gain (paper) | filter only, no NLM |",
            "|---|---|---|---|---|---|---|",
        ]
        u = rows[0]["nlm_unfiltered"] if rows else float("nan")
        pu = PAPER_TABLE1[c][TABLE1_FILTERS[0]][0]
        lines.append(
            f"| Input (before NLM) | - | {result['input_psnr'][c]:.2f} | "
            f"{PAPER_INPUT_PSNR[c]:.2f} | - | - | - |"
        )
        lines.append(f"| NLM, not filtered | - | ({u:.2f}, -, -) | ({pu:.2f}, -, -) | - | - | - |")
        for r in rows:
            p = r["paper"]
            ptxt = "-" if p is None else f"({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f})"
            pg = "-" if p is None else f"{p[1] - p[0]:+.2f} / {p[2] - p[0]:+.2f}"
            lines.append(
                f"| {{{r['order']}, {r['rho']:g}}} | {r['ripple_db']:.1f} | "
                f"({r['nlm_unfiltered']:.2f}, {r['nlm_filtered']:.2f}, {r['nlm_adaptive']:.2f}) | "
                f"{ptxt} | {r['gain_filtered']:+.2f} / {r['gain_adaptive']:+.2f} | {pg} | "
                f"{r['filtered_only']:.2f} / {r['adaptive_only']:.2f} |"
            )
        lines += [
            "",
            f"Ranking by NLM + adaptive (ours): {', '.join(_ranking(rows, c, 'nlm_adaptive'))}",
            "",
            f"Ranking by NLM after filter (ours): {', '.join(_ranking(rows, c, 'nlm_filtered'))}",
            "",
        ]
        paper_rank = sorted(PAPER_TABLE1[c].items(), key=lambda kv: -kv[1][2])
        lines += [
            "Ranking by NLM + adaptive (paper): "
            + ", ".join(f"{{{o}, {r:g}}}" for (o, r), _ in paper_rank),
            "",
        ]
    oracle = result.get("unfiltered_best_h")
    if oracle:
        lines += [
            "## Unfiltered baseline with NLM h tuned for it (oracle, on the evaluation scenes)",
            "",
            "| case | h grid: NLM on unfiltered input | best h | best PSNR | best filtered + "
            "adaptive (common h) | gap |",
            "|---|---|---|---|---|---|",
        ]
        for c in CASES:
            o = oracle[c]
            grid = ", ".join(f"{h:g}: {v:.2f}" for h, v in o["h_grid"].items())
            best_ad = max(r["nlm_adaptive"] for r in result["rows"] if r["case"] == c)
            lines.append(
                f"| {CASE_LABELS[c]} | {grid} | {o['best_h']:g} | {o['best_psnr']:.2f} | "
                f"{best_ad:.2f} | {best_ad - o['best_psnr']:+.2f} |"
            )
        lines.append("")
    lines.append(f"Run time: {result['seconds']:.1f} s.")
    return "\n".join(lines) + "\n"


TABLE1_CSV_FIELDS = (
    "case",
    "order",
    "rho",
    "ripple_db",
    "input",
    "nlm_unfiltered",
    "nlm_filtered",
    "nlm_adaptive",
    "gain_filtered",
    "gain_adaptive",
    "filtered_only",
    "adaptive_only",
    "paper_input",
    "paper_nlm_unfiltered",
    "paper_nlm_filtered",
    "paper_nlm_adaptive",
)


def plot_table1(result: dict, path: Path) -> Path:
    """Grouped bars per filter: ours (filtered, + adaptive) and the paper's, per case."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8), sharey=True)
    top = max(max(r["nlm_filtered"], r["nlm_adaptive"]) for r in result["rows"])
    for ax, c in zip(axes, CASES, strict=True):
        rows = [r for r in result["rows"] if r["case"] == c]
        x = np.arange(len(rows))
        w = 0.2
        ours_f = [r["nlm_filtered"] for r in rows]
        ours_a = [r["nlm_adaptive"] for r in rows]
        pap_f = [np.nan if r["paper"] is None else r["paper"][1] for r in rows]
        pap_a = [np.nan if r["paper"] is None else r["paper"][2] for r in rows]
        ax.bar(x - 1.5 * w, ours_f, w, label="ours: NLM after filter", color="tab:blue")
        ax.bar(x - 0.5 * w, ours_a, w, label="ours: + adaptive", color="tab:cyan")
        ax.bar(x + 0.5 * w, pap_f, w, label="paper: filtered", color="tab:orange")
        ax.bar(x + 1.5 * w, pap_a, w, label="paper: + adaptive", color="gold")
        ax.axhline(
            rows[0]["nlm_unfiltered"],
            color="tab:blue",
            ls="--",
            lw=1,
            label="ours: NLM, not filtered",
        )
        ax.axhline(
            PAPER_TABLE1[c][TABLE1_FILTERS[0]][0],
            color="tab:orange",
            ls="--",
            lw=1,
            label="paper: NLM, not filtered",
        )
        ax.axhline(result["input_psnr"][c], color="gray", ls=":", lw=1, label="ours: input")
        ax.set_xticks(x, [f"{{{r['order']}, {r['rho']:g}}}" for r in rows], rotation=30)
        ax.set_title(f"{CASE_LABELS[c]} (input {result['input_psnr'][c]:.2f} dB)")
        ax.set_ylim(18, max(34.0, top + 1.0))
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("PSNR after NLM [dB]")
    handles, labels = axes[1].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=4)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def write_table1(result: dict, out: Path) -> dict[str, Path]:
    """table1.csv / .json / .md / .png in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / f"table1.{k}" for k in ("csv", "json", "md", "png")}
    with open(paths["csv"], "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=TABLE1_CSV_FIELDS)
        wr.writeheader()
        for r in result["rows"]:
            p = r["paper"] or [None, None, None]
            wr.writerow(
                {k: r[k] for k in TABLE1_CSV_FIELDS[:12]}
                | {
                    "paper_input": PAPER_INPUT_PSNR[r["case"]],
                    "paper_nlm_unfiltered": p[0],
                    "paper_nlm_filtered": p[1],
                    "paper_nlm_adaptive": p[2],
                }
            )
    paths["json"].write_text(json.dumps(result, indent=1))
    paths["md"].write_text(table1_markdown(result))
    plot_table1(result, paths["png"])
    return paths


# ----------------------------------------------------------------------------------------------
# NLM tuning (run once, on a seed outside the evaluation seeds)
# ----------------------------------------------------------------------------------------------


def tune_nlm(
    seed: int = 100,
    size: int = 204,
    patch_sizes: Sequence[int] = (5, 7),
    h_grid: Sequence[float] = (0.5, 0.8, 1.0, 1.2, 1.5, 2.0, 3.0, 4.0, 6.0),
    filter_: tuple[int, float] = (20, 0.14),
) -> dict:
    """Grid over (patch, h) on one scene: NLM on unfiltered / filtered / filtered + adaptive input,
    both cases. ``best`` maximises the mean over both cases of the filtered + adaptive PSNR."""
    data = make_synthetic_data((seed,), size)
    ((order, rho),) = _check_filters([filter_])
    grid = []
    for c in CASES:
        x = data.inputs[c]
        filtered, adaptive, _ = _filter_outputs(x, data.amplitude, order, rho)
        for ps in patch_sizes:
            for hh in h_grid:
                s = NLMSettings(int(ps), 10, float(hh)).validate()
                v = [_psnr_list(s(y, data.sigma), data.depth)[0] for y in (x, filtered, adaptive)]
                grid.append(
                    {
                        "case": c,
                        "patch_size": ps,
                        "h": hh,
                        "nlm_unfiltered": v[0],
                        "nlm_filtered": v[1],
                        "nlm_adaptive": v[2],
                    }
                )
    score: dict[tuple[int, float], list[float]] = {}
    for g in grid:
        score.setdefault((g["patch_size"], g["h"]), []).append(g["nlm_adaptive"])
    best = max(score, key=lambda k: float(np.mean(score[k])))
    return {
        "seed": seed,
        "filter": [order, rho],
        "grid": grid,
        "best": {"patch_size": best[0], "h": best[1], "score": float(np.mean(score[best]))},
    }


# ----------------------------------------------------------------------------------------------
# Fig. 9
# ----------------------------------------------------------------------------------------------


def run_fig9(
    seeds: Sequence[int] = (0, 1, 2),
    size: int = 204,
    odd_orders: Sequence[int] = FIG9_ODD_ORDERS,
    even_orders: Sequence[int] = FIG9_EVEN_ORDERS,
    rhos: Sequence[float] = FIG9_RHOS,
    nlm: NLMSettings | None = None,
    case: str = "fpn+noise",
    *,
    progress: bool = True,
) -> dict:
    """PSNR after NLM for every (order, rho) of the family, with and without adaptation.

    One noisy input per scene is reused for all filters; ``case`` is ``'fpn+noise'`` (default, the
    must-show case) or ``'fpn'``. Returns a JSON-able dict with ``cells`` (one per order x rho).
    """
    nlm = (nlm or NLMSettings()).validate()
    if case not in CASES:
        raise ValueError(f"case must be one of {CASES}, got {case!r}")
    for name, orders in (("odd_orders", odd_orders), ("even_orders", even_orders)):
        want = 1 if name == "odd_orders" else 0
        bad = [
            o
            for o in orders
            if isinstance(o, bool) or not isinstance(o, int) or o < 3 or o % 2 != want
        ]
        if bad or not orders:
            raise ValueError(
                f"{name} must be a non-empty list of {'odd' if want else 'even'} "
                f"ints >= 3, got {list(orders)!r}"
            )
    rhos = [float(r) for r in rhos]
    if not rhos or any(not (0 < r <= 1 / 6) for r in rhos):
        raise ValueError(f"rhos must be a non-empty list in (0, 1/6], got {rhos!r}")
    t0 = time.perf_counter()
    data = make_synthetic_data(seeds, size)
    x, gt, amp, sig = data.inputs[case], data.depth, data.amplitude, data.sigma
    input_psnr = float(np.mean(_psnr_list(x, gt)))
    unf = float(np.mean(_psnr_list(nlm(x, sig), gt)))
    jobs = [(o, r) for o in list(even_orders) + list(odd_orders) for r in rhos]
    it = jobs
    if progress:
        from tqdm import tqdm

        it = tqdm(jobs, desc="fig9 (order, rho)", unit="filter")
    cells = []
    for order, rho in it:
        filtered, adaptive, ripple_db = _filter_outputs(x, amp, order, rho)
        both = nlm(torch.cat([filtered, adaptive]), torch.cat([sig, sig]))
        v = _psnr_list(both, torch.cat([gt, gt]))
        S = len(data.seeds)
        cells.append(
            {
                "parity": "odd" if order % 2 else "even",
                "order": order,
                "rho": rho,
                "ripple_db": ripple_db,
                "nlm_filtered": float(np.mean(v[:S])),
                "nlm_adaptive": float(np.mean(v[S:])),
            }
        )
    best = {}
    for parity in ("even", "odd"):
        for key in ("nlm_filtered", "nlm_adaptive"):
            cs = [c for c in cells if c["parity"] == parity]
            b = max(cs, key=lambda c, k=key: c[k])
            best[f"{parity}/{key}"] = {"order": b["order"], "rho": b["rho"], "psnr": b[key]}
    return {
        "experiment": "fig9",
        "case": case,
        "seeds": list(data.seeds),
        "size": list(data.size),
        "nlm": asdict(nlm),
        "input_psnr": input_psnr,
        "nlm_unfiltered": unf,
        "odd_orders": list(odd_orders),
        "even_orders": list(even_orders),
        "rhos": rhos,
        "cells": cells,
        "best": best,
        "seconds": time.perf_counter() - t0,
    }


def _fig9_matrix(result: dict, parity: str, key: str) -> tuple[list[int], np.ndarray]:
    orders = result["even_orders"] if parity == "even" else result["odd_orders"]
    m = np.full((len(orders), len(result["rhos"])), np.nan)
    for c in result["cells"]:
        if c["parity"] == parity:
            m[orders.index(c["order"]), result["rhos"].index(c["rho"])] = c[key]
    return orders, m


def plot_fig9(result: dict, path: Path) -> Path:
    """2 x 2 heat maps (rows even / odd orders, columns without / with adaptation), Fig. 9."""
    plt = _pyplot()
    mats = {
        (p, k): _fig9_matrix(result, p, k)
        for p in ("even", "odd")
        for k in ("nlm_filtered", "nlm_adaptive")
    }
    allv = np.concatenate([m.ravel() for _, m in mats.values()])
    # colour scale from 3 dB below NLM on the unfiltered input (darker cells: worse than that;
    # low orders with small rho have large passband ripple and fall far below)
    vmax = float(np.nanmax(allv))
    vmin = max(float(np.nanmin(allv)), min(result["nlm_unfiltered"] - 3.0, vmax - 1.0))
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    rhos = result["rhos"]
    for i, p in enumerate(("even", "odd")):
        for j, k in enumerate(("nlm_filtered", "nlm_adaptive")):
            orders, m = mats[(p, k)]
            ax = axes[i, j]
            im = ax.imshow(
                np.clip(m, vmin, None),
                aspect="auto",
                origin="lower",
                vmin=vmin,
                vmax=vmax,
                cmap="viridis",
            )
            ax.set_yticks(range(len(orders)), [str(o) for o in orders])
            step = max(1, (len(rhos) + 6) // 7)
            ax.set_xticks(range(0, len(rhos), step), [f"{r:g}" for r in rhos[::step]])
            bi, bj = np.unravel_index(np.nanargmax(m), m.shape)
            ax.plot(bj, bi, "r*", ms=10)
            ax.set_title(
                f"{p} orders, {'with' if j else 'without'} adaptation "
                f"(best {{{orders[bi]}, {rhos[bj]:g}}}: {m[bi, bj]:.2f} dB)",
                fontsize=9,
            )
            ax.set_xlabel("rho (transition bandwidth)")
            ax.set_ylabel("order")
            fig.colorbar(im, ax=ax, label="PSNR after NLM [dB] (clipped below)")
    fig.suptitle(
        f"Fig. 9: NLM after FPN suppression, {CASE_LABELS[result['case']]} "
        f"(input {result['input_psnr']:.2f} dB, NLM unfiltered "
        f"{result['nlm_unfiltered']:.2f} dB)",
        fontsize=10,
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=70)
    plt.close(fig)
    return path


def fig9_markdown(result: dict) -> str:
    lines = [
        f"# Fig. 9: PSNR [dB] after NLM, {CASE_LABELS[result['case']]}",
        "",
        f"Scenes: seeds {result['seeds']}, {result['size'][0]} x {result['size'][1]}; input "
        f"{result['input_psnr']:.2f} dB, NLM on the unfiltered input {result['nlm_unfiltered']:.2f}"
        f" dB. NLM: {result['nlm']}. The paper gives Fig. 9 only as a picture; its Table I best "
        "cells are {20, 0.14} and {28, 0.13} (even orders).",
        "",
        "| best | {order, rho} | PSNR | gain over NLM unfiltered |",
        "|---|---|---|---|",
    ]
    for name, b in result["best"].items():
        lines.append(
            f"| {name} | {{{b['order']}, {b['rho']:g}}} | {b['psnr']:.2f} | "
            f"{b['psnr'] - result['nlm_unfiltered']:+.2f} |"
        )
    lines.append("")
    for p in ("even", "odd"):
        for k in ("nlm_filtered", "nlm_adaptive"):
            orders, m = _fig9_matrix(result, p, k)
            lines += [
                f"## {p} orders, {'with' if k == 'nlm_adaptive' else 'without'} adaptation",
                "",
                "| order \\ rho | " + " | ".join(f"{r:g}" for r in result["rhos"]) + " |",
                "|---" * (len(result["rhos"]) + 1) + "|",
            ]
            for o, row in zip(orders, m, strict=True):
                lines.append(f"| {o} | " + " | ".join(f"{v:.2f}" for v in row) + " |")
            lines.append("")
    lines.append(f"Run time: {result['seconds']:.1f} s.")
    return "\n".join(lines) + "\n"


def write_fig9(result: dict, out: Path) -> dict[str, Path]:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {k: out / f"fig9.{k}" for k in ("csv", "json", "md", "png")}
    fields = ("parity", "order", "rho", "ripple_db", "nlm_filtered", "nlm_adaptive")
    with open(paths["csv"], "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=fields)
        wr.writeheader()
        for c in result["cells"]:
            wr.writerow({k: c[k] for k in fields})
    paths["json"].write_text(json.dumps(result, indent=1))
    paths["md"].write_text(fig9_markdown(result))
    plot_fig9(result, paths["png"])
    return paths


# ----------------------------------------------------------------------------------------------
# Demo
# ----------------------------------------------------------------------------------------------


@dataclass
class DemoResult:
    """PSNRs (dB) of the demo's stages, the files written and the run time."""

    psnr: dict[str, float]
    filter: tuple[int, float] = (28, 0.13)
    paths: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0

    def summary(self) -> str:
        p = self.psnr
        return "\n".join(
            [
                "tof-fpn demo: synthetic scene -> eq. (10) FPN + eq. (2) noise -> FPN suppression "
                f"{{{self.filter[0]}, {self.filter[1]:g}}} + adaptive fusion (eq. 11) -> NLM",
                f"  input (FPN + noise)          : {p['input']:6.2f} dB PSNR",
                f"  NLM only (no FPN filter)     : {p['nlm_only']:6.2f} dB",
                f"  FPN filter + fusion          : {p['filtered']:6.2f} dB",
                f"  FPN filter + fusion + NLM    : {p['denoised']:6.2f} dB "
                f"({p['denoised'] - p['nlm_only']:+.2f} dB vs NLM only)",
                f"  picture: {self.paths.get('png', '-')}  ({self.seconds:.1f} s)",
            ]
        )


def run_demo(
    out: Path,
    seed: int = 0,
    size: int = 204,
    order: int = 28,
    rho: float = 0.13,
    nlm: NLMSettings | None = None,
    dpi: int = 60,
) -> DemoResult:
    """One scene end to end; writes ``demo.png`` (amplitude, GT, input, NLM only, filtered,
    filtered + NLM, PSNR in the titles) and ``demo.json`` into ``out``.

    Default filter {28, 0.13}: the paper's second best in Table I and the best of its six filters
    in our Table I run (docs/experiments.md); ``FPNSuppression()``'s default is {20, 0.14}."""
    t0 = time.perf_counter()
    nlm = (nlm or NLMSettings()).validate()
    ((order, rho),) = _check_filters([(order, rho)])
    if isinstance(dpi, bool) or not isinstance(dpi, int) or not 10 <= dpi <= 600:
        raise ValueError(f"dpi must be an int in [10, 600], got {dpi!r}")
    data = make_synthetic_data((seed,), size)
    x, gt, amp, sig = data.inputs["fpn+noise"], data.depth, data.amplitude, data.sigma
    stage = FPNSuppression(order, rho, adaptive=True)
    filtered = stage(x, amp)
    images = {
        "ground truth": gt,
        "input (FPN + noise)": x,
        "NLM only": nlm(x, sig),
        f"FPN filter {{{order}, {rho:g}}} + fusion": filtered,
        "FPN filter + fusion + NLM": nlm(filtered, sig),
    }
    keys = ("gt", "input", "nlm_only", "filtered", "denoised")
    vals = {k: _psnr_list(v, gt)[0] for k, v in zip(keys, images.values(), strict=True)}
    vals["gt"] = math.inf
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plt = _pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(12, 7.6))
    ax = axes[0, 0]
    im = ax.imshow(amp[0, 0].numpy(), cmap="gray")
    ax.set_title("amplitude A (low sensing, 0..300)", fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.046)
    for ax, (title, img), k in zip(axes.ravel()[1:], images.items(), keys, strict=True):
        im = ax.imshow(img[0, 0].numpy(), cmap="turbo", vmin=0.0, vmax=D_MAX)
        ax.set_title(title if k == "gt" else f"{title}\nPSNR {vals[k]:.2f} dB", fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.046, label="m")
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    png = out / "demo.png"
    fig.savefig(png, dpi=dpi)
    plt.close(fig)
    res = DemoResult(
        psnr={k: v for k, v in vals.items() if k != "gt"},
        filter=(order, rho),
        paths={"png": str(png), "json": str(out / "demo.json")},
        seconds=time.perf_counter() - t0,
    )
    (out / "demo.json").write_text(
        json.dumps(
            {
                "seed": seed,
                "size": size,
                "filter": [order, rho],
                "nlm": asdict(nlm),
                "nlm_sigma": float(sig[0]),
                "lambda": data.lam[0],
                "psnr": res.psnr,
            },
            indent=1,
        )
    )
    return res
