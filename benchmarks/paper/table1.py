"""Table I of Georgiev, Bregovic, Gotchev (SAS 2015): PSNR after NLM, without and with filtering.

Protocol and reading of the table: :mod:`tof_fpn_torch.experiments.common` and docs/experiments.md.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from tof_fpn_torch import constants as K
from tof_fpn_torch.paper_data import (
    CASE_LABELS,
    CASES,
    NLMSettings,
    check_filters,
    filter_outputs,
    make_synthetic_data,
    psnr_list,
)
from tof_fpn_torch.plotting import pyplot

from .report import write_report

__all__ = [
    "TABLE1_CSV_FIELDS",
    "plot_table1",
    "run_table1",
    "table1_markdown",
    "tune_nlm",
    "write_table1",
]


def run_table1(
    seeds: Sequence[int] = (0, 1, 2),
    size: int = K.CAMCUBE_SIZE,
    filters: Sequence[tuple[int, float]] = K.TABLE1_FILTERS,
    nlm: NLMSettings | None = None,
    *,
    best_h_grid: Sequence[float] | None = (0.8, 1.2, 2.0, 3.0, 4.0, 6.0, 8.0),
    compensate_delay: bool = False,
    progress: bool = False,
) -> dict:
    """Table I's protocol; returns a JSON-able dict (``rows``: one per case x filter, seed means).

    ``best_h_grid``: also run NLM on the unfiltered input at each ``h`` and report the best one per
    case (an oracle-tuned baseline, on the evaluation scenes themselves), to show how much of the
    gain depends on using one NLM setting for all columns. ``None`` skips it.
    ``compensate_delay``: odd orders with :class:`~tof_fpn_torch.FPNFilter`'s half-sample
    interpolator (output on the input grid); the paper's filters have no compensation.
    Every filter runs twice: the paper's unconstrained design (the ``nlm_*`` columns, compared
    with the paper) and the unit-DC design (``*_unit_dc``): the minimax design puts a ripple
    extremum at w = 0, so depth comes out scaled by ``H(0)``, e.g. 0.967 for {20, 0.14}.
    """
    nlm = (nlm or NLMSettings()).validate()
    filters = check_filters(filters)
    t0 = time.perf_counter()
    data = make_synthetic_data(seeds, size)
    gt, amp, sigma = data.depth, data.amplitude, data.sigma
    x = torch.cat([data.inputs[c] for c in CASES])  # (2S, 1, H, W): both cases in one batch
    gt2, amp2, sig2 = torch.cat([gt, gt]), torch.cat([amp, amp]), torch.cat([sigma, sigma])
    S = len(data.seeds)

    def split(v: list[float]) -> dict[str, list[float]]:
        return {c: v[i * S : (i + 1) * S] for i, c in enumerate(CASES)}

    input_psnr = split(psnr_list(x, gt2))
    nlm_unf = split(psnr_list(nlm(x, sig2), gt2))
    rows = []
    it = filters
    if progress:
        from tqdm import tqdm

        it = tqdm(filters, desc="table1 filters", unit="filter")
    for order, rho in it:
        filtered, adaptive, ripple_db = filter_outputs(x, amp2, order, rho, compensate_delay)
        unit_f, unit_a, _ = filter_outputs(x, amp2, order, rho, compensate_delay, unit_dc=True)
        vals = {
            "filtered_only": split(psnr_list(filtered, gt2)),
            "adaptive_only": split(psnr_list(adaptive, gt2)),
            "nlm_filtered": split(psnr_list(nlm(filtered, sig2), gt2)),
            "nlm_adaptive": split(psnr_list(nlm(adaptive, sig2), gt2)),
            "nlm_filtered_unit_dc": split(psnr_list(nlm(unit_f, sig2), gt2)),
            "nlm_adaptive_unit_dc": split(psnr_list(nlm(unit_a, sig2), gt2)),
        }
        for c in CASES:
            paper = K.PAPER_TABLE1[c].get((order, rho))
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
                "nlm_filtered_unit_dc": float(np.mean(vals["nlm_filtered_unit_dc"][c])),
                "nlm_adaptive_unit_dc": float(np.mean(vals["nlm_adaptive_unit_dc"][c])),
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
            per_h[float(hh)] = split(psnr_list(s(x, sig2), gt2))
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
        "input_psnr": {c: float(np.mean(v)) for c, v in input_psnr.items()},
        "input_psnr_per_seed": input_psnr,
        "nlm_unfiltered_per_seed": nlm_unf,
        "paper_input_psnr": K.PAPER_INPUT_PSNR,
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
        "adaptive fusion eq. 11) with the paper's unconstrained filters; 'Input' is the PSNR "
        "before any processing. 'paper' is Table I. 'unit DC' repeats the filtered columns with "
        "this package's default design, constrained to H(0) = 1 (no depth bias).",
        "",
    ]
    variants = [k for k in ("compensate_delay",) if result.get(k)]
    if variants:
        lines += [f"**Variant (not the paper's filters): {', '.join(variants)}.**", ""]
    for c in CASES:
        rows = [r for r in result["rows"] if r["case"] == c]
        lines += [
            f"## {CASE_LABELS[c]}: input {result['input_psnr'][c]:.2f} dB "
            f"(paper {K.PAPER_INPUT_PSNR[c]:.2f} dB)",
            "",
            "| {order, rho} | ripple dB | ours (not filt., filt., +adapt.) | paper | "
            "gain filt. / +adapt. (ours) | gain (paper) | unit DC: filt., +adapt. | "
            "filter only, no NLM |",
            "|---|---|---|---|---|---|---|---|",
        ]
        u = rows[0]["nlm_unfiltered"] if rows else float("nan")
        pu = K.PAPER_TABLE1[c][K.TABLE1_FILTERS[0]][0]
        lines.append(
            f"| Input (before NLM) | - | {result['input_psnr'][c]:.2f} | "
            f"{K.PAPER_INPUT_PSNR[c]:.2f} | - | - | - | - |"
        )
        lines.append(
            f"| NLM, not filtered | - | ({u:.2f}, -, -) | ({pu:.2f}, -, -) | - | - | - | - |"
        )
        for r in rows:
            p = r["paper"]
            ptxt = "-" if p is None else f"({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f})"
            pg = "-" if p is None else f"{p[1] - p[0]:+.2f} / {p[2] - p[0]:+.2f}"
            lines.append(
                f"| {{{r['order']}, {r['rho']:g}}} | {r['ripple_db']:.1f} | "
                f"({r['nlm_unfiltered']:.2f}, {r['nlm_filtered']:.2f}, {r['nlm_adaptive']:.2f}) | "
                f"{ptxt} | {r['gain_filtered']:+.2f} / {r['gain_adaptive']:+.2f} | {pg} | "
                f"{r['nlm_filtered_unit_dc']:.2f}, {r['nlm_adaptive_unit_dc']:.2f} | "
                f"{r['filtered_only']:.2f} / {r['adaptive_only']:.2f} |"
            )
        lines += [
            "",
            f"Ranking by NLM + adaptive (ours): {', '.join(_ranking(rows, c, 'nlm_adaptive'))}",
            "",
            f"Ranking by NLM after filter (ours): {', '.join(_ranking(rows, c, 'nlm_filtered'))}",
            "",
        ]
        paper_rank = sorted(K.PAPER_TABLE1[c].items(), key=lambda kv: -kv[1][2])
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
    "nlm_filtered_unit_dc",
    "nlm_adaptive_unit_dc",
    "paper_input",
    "paper_nlm_unfiltered",
    "paper_nlm_filtered",
    "paper_nlm_adaptive",
)


def plot_table1(result: dict, path: Path) -> Path:
    """Grouped bars per filter: ours (filtered, + adaptive) and the paper's, per case."""
    plt = pyplot()
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
            K.PAPER_TABLE1[c][K.TABLE1_FILTERS[0]][0],
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
    rows = []
    for r in result["rows"]:
        p = r["paper"] or [None, None, None]
        rows.append(
            r
            | {
                "paper_input": K.PAPER_INPUT_PSNR[r["case"]],
                "paper_nlm_unfiltered": p[0],
                "paper_nlm_filtered": p[1],
                "paper_nlm_adaptive": p[2],
            }
        )
    return write_report(
        out, "table1", result, TABLE1_CSV_FIELDS, rows, table1_markdown(result), plot_table1
    )


def tune_nlm(
    seed: int = 100,
    size: int = K.CAMCUBE_SIZE,
    patch_sizes: Sequence[int] = (5, 7),
    h_grid: Sequence[float] = (0.5, 0.8, 1.0, 1.2, 1.5, 2.0, 3.0, 4.0, 6.0),
    filter_: tuple[int, float] = (20, 0.14),
) -> dict:
    """Grid over (patch, h) on one scene: NLM on unfiltered / filtered / filtered + adaptive input,
    both cases. ``best`` maximises the mean over both cases of the filtered + adaptive PSNR."""
    data = make_synthetic_data((seed,), size)
    ((order, rho),) = check_filters([filter_])
    grid = []
    for c in CASES:
        x = data.inputs[c]
        filtered, adaptive, _ = filter_outputs(x, data.amplitude, order, rho)
        for ps in patch_sizes:
            for hh in h_grid:
                s = NLMSettings(int(ps), 10, float(hh)).validate()
                v = [psnr_list(s(y, data.sigma), data.depth)[0] for y in (x, filtered, adaptive)]
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
