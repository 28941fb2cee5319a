"""The demo: one synthetic low-sensing scene end to end (FPN + noise -> FPN suppression -> NLM)."""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from . import constants as K
from .build import suppression_from_design
from .paper_data import NLMSettings, check_filters, make_synthetic_data, psnr_list
from .plotting import pyplot

__all__ = ["DemoResult", "run_demo"]


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
    size: int = K.CAMCUBE_SIZE,
    order: int = 28,
    rho: float = 0.13,
    nlm: NLMSettings | None = None,
    dpi: int = 60,
) -> DemoResult:
    """One scene end to end; writes ``demo.png`` (amplitude, GT, input, NLM only, filtered,
    filtered + NLM, PSNR in the titles) and ``demo.json`` into ``out``.

    Default filter {28, 0.13}: the paper's second best in Table I and the best of its six filters
    in our Table I run (docs/experiments.md); ``suppression_from_design()``'s default is {20, 0.14}."""
    t0 = time.perf_counter()
    nlm = (nlm or NLMSettings()).validate()
    ((order, rho),) = check_filters([(order, rho)])
    if isinstance(dpi, bool) or not isinstance(dpi, int) or not 10 <= dpi <= 600:
        raise ValueError(f"dpi must be an int in [10, 600], got {dpi!r}")
    data = make_synthetic_data((seed,), size)
    x, gt, amp, sig = data.inputs["fpn+noise"], data.depth, data.amplitude, data.sigma
    stage = suppression_from_design(order, rho, adaptive=True)
    filtered = stage(x, amp)
    images = {
        "ground truth": gt,
        "input (FPN + noise)": x,
        "NLM only": nlm(x, sig),
        f"FPN filter {{{order}, {rho:g}}} + fusion": filtered,
        "FPN filter + fusion + NLM": nlm(filtered, sig),
    }
    keys = ("gt", "input", "nlm_only", "filtered", "denoised")
    vals = {k: psnr_list(v, gt)[0] for k, v in zip(keys, images.values(), strict=True)}
    vals["gt"] = math.inf
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(12, 7.6))
    ax = axes[0, 0]
    im = ax.imshow(amp[0, 0].numpy(), cmap="gray")
    ax.set_title("amplitude A (low sensing, 0..300)", fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.046)
    for ax, (title, img), k in zip(axes.ravel()[1:], images.items(), keys, strict=True):
        im = ax.imshow(img[0, 0].numpy(), cmap="turbo", vmin=0.0, vmax=K.D_MAX)
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
