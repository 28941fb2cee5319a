"""Table II of Georgiev, Bregovic, Gotchev (SAS 2015): denoising of low-sensing data without and
with FPN suppression, on the raw-level simulator (the paper's data are real CamCube 2.0 captures).

Protocol (Sec. IV-A, IV-C; our choices where the paper gives none; results in docs/denoise.md):

* **Scene**: :func:`~tof_fpn_torch.sim.planar_scene` -- fronto-parallel boards of different
  materials and textures at several depths in front of a wall -- with the illumination falling
  off towards the image corners (``cos^4`` of the field angle, ``fov_deg`` across the width;
  folded into the reflectance, since the simulator's light source is uniform). Layout seed,
  board depths, falloff and the illumination power were chosen so that the shares of low-sensing
  pixels (``A < 300``) are Table II's 100 / 94 / 83 % at 50 / 100 / 200 us; the ambient
  irradiance so that the unprocessed input is near Table II's "No denoising" row (shot noise of
  the background light dominates, as the paper's ~3 dB per doubling of the time indicates).
  Everything else is the simulator's default chain (photons, shot noise, column read-out FPN at
  2pi/3 and pi, read noise, ADC; 16-bit so that 2 ms does not clip).
* **Ground truth**: the mean of :data:`~tof_fpn_torch.constants.TABLE2_GT_FRAMES` (200) frames
  at 2000 us, as the paper (``gt_frames`` fewer with ``--quick``).
* **Test data**: ``frames`` captures per integration time (50, 100, 200 us); PSNR (eq. 9,
  ``D_MAX`` = 7.5 m) over the pixels with a valid ground truth, mean of the dB values over the
  frames. LOW / IMP: :func:`~tof_fpn_torch.analysis.metrics.sensing_stats` (IMP: invalid or more
  than 0.5 m from the ground truth).
* **FPN suppression**: the paper's stage, ``{20, 0.14}`` notch along the rows plus the eq. (11)
  amplitude fusion (70 / 350), ungated (``suppression_from_design(gate=False)``, unit-DC taps
  unless ``unit_dc=False``).
* **Denoisers**: NLM, HypBi, LPA-ICI, BM3D, sDCT from :mod:`tof_fpn_torch.denoise` with their
  default settings and the amplitude (noise ``sigma_D = k / A``, ``k`` estimated per frame; the
  guide of HypBi), the same for the unfiltered and the filtered input.
"""

from __future__ import annotations

import inspect
import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from tof_fpn_torch import constants as K
from tof_fpn_torch.analysis.metrics import psnr, sensing_stats
from tof_fpn_torch.build import suppression_from_design
from tof_fpn_torch.denoise import estimate_noise_k
from tof_fpn_torch.denoise import get as get_denoiser
from tof_fpn_torch.plotting import pyplot
from tof_fpn_torch.runtime import valid_mask
from tof_fpn_torch.sim import Camera, Scene, Simulation, planar_scene

from .report import write_report

__all__ = [
    "PAPER_METHODS",
    "TABLE2_CSV_FIELDS",
    "Table2Setup",
    "plot_table2",
    "run_table2",
    "table2_markdown",
    "table2_scene",
    "table2_simulation",
    "write_table2",
]

#: The paper's denoisers in its row order (registry names).
PAPER_METHODS: tuple[str, ...] = ("nlm", "hypbi", "lpa-ici", "bm3d", "sdct")
LABELS = {
    "none": "No denoising",
    "nlm": "NLM",
    "hypbi": "HypBi",
    "lpa-ici": "LPA-ICI",
    "bm3d": "BM3D",
    "sdct": "sDCT",
    "bilateral": "Bilateral",
    "joint-bilateral": "Joint bilateral",
    "guided": "Guided",
}


@dataclass(frozen=True)
class Table2Setup:
    """The simulated capture of Table II (see the module docstring for how it was set)."""

    size: int = K.CAMCUBE_SIZE
    frames: int = 3
    gt_frames: int = K.TABLE2_GT_FRAMES
    scene_seed: int = 2
    depths: tuple[float, ...] = (1.0, 1.5, 2.0, 2.5, 3.0, 3.5)
    fov_deg: float = 90.0
    illumination_power: float = 0.675
    ambient_irradiance: float = 1.0
    adc_bits: int = 16
    full_well: float = 5e6
    seed: int = 0

    def validate(self) -> Table2Setup:
        for name in ("size", "frames", "gt_frames", "scene_seed", "adc_bits", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name} must be an int >= 0, got {v!r}")
        if self.size < 32 or self.frames < 1 or self.gt_frames < 1:
            raise ValueError(
                f"size must be >= 32 and frames, gt_frames >= 1, got {self.size}, "
                f"{self.frames}, {self.gt_frames}"
            )
        if not (0.0 < self.fov_deg < 180.0):
            raise ValueError(f"fov_deg must lie in (0, 180), got {self.fov_deg!r}")
        return self


def table2_scene(setup: Table2Setup) -> Scene:
    """The planar scene with the illumination falloff folded into the reflectance."""
    n = setup.size
    sc = planar_scene(n, n, seed=setup.scene_seed, depths=setup.depths)
    u = torch.linspace(-1.0, 1.0, n, dtype=torch.float64)
    yy, xx = torch.meshgrid(u, u, indexing="ij")
    half = math.radians(setup.fov_deg / 2.0)
    field = torch.atan(torch.sqrt(yy.square() + xx.square()) * math.tan(half))
    falloff = torch.cos(field) ** 4
    refl = (sc.reflectance.double() * falloff).clamp(1e-3, 1.0).to(sc.depth.dtype)
    return Scene(sc.depth, refl)


def table2_simulation(setup: Table2Setup, integration_time: float) -> Simulation:
    """The default raw-level chain with this setup's camera at ``integration_time`` (s)."""
    cam = Camera(
        integration_time=integration_time,
        illumination_power=setup.illumination_power,
        ambient_irradiance=setup.ambient_irradiance,
        adc_bits=setup.adc_bits,
        full_well=setup.full_well,
    )
    return Simulation(cam)


def _db(v: torch.Tensor) -> float:
    return float(v.double().mean())


def run_table2(
    setup: Table2Setup | None = None,
    methods: Sequence[str] = PAPER_METHODS,
    *,
    unit_dc: bool = True,
    noise: str = "own",
    progress: bool = False,
) -> dict:
    """Table II's protocol; returns a dict (``rows``: one per integration time; ``_images``: the
    50 us frames for the figure, dropped from the JSON).

    ``noise``: ``"own"`` -- each denoiser estimates ``k`` of ``sigma_D = k / A`` on its own input
    (as a user runs it); ``"input"`` -- ``k`` estimated on each unfiltered frame and given to the
    denoisers for both columns (the notch lowers the wavelet estimate on the filtered frame)."""
    if noise not in ("own", "input"):
        raise ValueError(f"noise must be 'own' or 'input', got {noise!r}")
    setup = (setup or Table2Setup()).validate()
    methods = list(methods)
    for m in methods:
        get_denoiser(m)  # unknown names fail before the simulation
    t0 = time.perf_counter()
    scene = table2_scene(setup)
    gt_run = table2_simulation(setup, K.TABLE2_GT_INTEGRATION_TIME).run(
        scene, frames=setup.gt_frames, seed=setup.seed
    )
    gt = gt_run.depth.double().mean(0, keepdim=True).float()
    stage = suppression_from_design(gate=False, unit_dc=unit_dc)
    dens = {m: get_denoiser(m) for m in methods}
    rows = []
    images: dict[str, np.ndarray] = {"gt": gt[0, 0].numpy()}
    its = list(K.TABLE2_INTEGRATION_TIMES)
    it_iter = its
    if progress:
        from tqdm import tqdm

        it_iter = tqdm(its, desc="table2 integration times", unit="IT")
    for j, it in enumerate(it_iter):
        run = table2_simulation(setup, it).run(scene, frames=setup.frames, seed=setup.seed + 1 + j)
        d, a = run.depth, run.amplitude
        g = gt.expand_as(d)
        st = sensing_stats(d, a, reference=g)
        with torch.no_grad():
            filt = stage(d, a)
        res = {"none": [_db(psnr(d, g)), _db(psnr(filt, g))]}
        outs = {}
        for m, den in dens.items():
            o0, o1 = _denoise_pair(m, den, d, filt, a, noise)
            res[m] = [_db(psnr(o0, g)), _db(psnr(o1, g))]
            outs[m] = (o0, o1)
        paper_low, paper_imp = K.PAPER_TABLE2_SENSING[j]
        row = {
            "integration_time_us": round(it * 1e6),
            "low": _db(st["low"]),
            "imp": _db(st["imp"]),
            "paper_low": paper_low,
            "paper_imp": paper_imp,
            "psnr": res,
            "paper": {
                m: list(K.PAPER_TABLE2[m][j]) for m in ["none", *methods] if m in K.PAPER_TABLE2
            },
            "amplitude_median": float(a.median()),
        }
        rows.append(row)
        if j == 0:
            images["input"] = d[0, 0].numpy()
            images["input_filtered"] = filt[0, 0].numpy()
            for m, (o0, o1) in outs.items():
                images[m] = o0[0, 0].numpy()
                images[m + "_filtered"] = o1[0, 0].numpy()
    return {
        "experiment": "table2",
        "setup": asdict(setup),
        "methods": methods,
        "unit_dc": bool(unit_dc),
        "noise": noise,
        "gt_saturated_share": float(gt_run.saturated.float().mean()),
        "rows": rows,
        "seconds": time.perf_counter() - t0,
        "_images": images,
    }


def _denoise_pair(m, den, d, filt, a, noise):
    """The denoiser on the unfiltered and the filtered frames (``noise``: see run_table2)."""
    if noise == "own" or "k" not in inspect.signature(type(den).__init__).parameters:
        return den(d, a), den(filt, a)
    pairs = []
    valid = valid_mask(d) & valid_mask(d, a, signed=True)  # the denoisers' own rule
    for b in range(d.shape[0]):
        xb = torch.where(valid[b : b + 1], d[b : b + 1], torch.zeros_like(d[b : b + 1]))
        k = float(estimate_noise_k(xb, a[b : b + 1], valid[b : b + 1]).flatten()[0])
        dk = get_denoiser(m, k=k)
        pairs.append((dk(d[b : b + 1], a[b : b + 1]), dk(filt[b : b + 1], a[b : b + 1])))
    return torch.cat([p[0] for p in pairs]), torch.cat([p[1] for p in pairs])


def _rank(values: dict[str, float]) -> list[str]:
    return [LABELS.get(k, k) for k, _ in sorted(values.items(), key=lambda kv: -kv[1])]


def table2_markdown(result: dict) -> str:
    """Markdown: ours beside Table II, the gains from FPN suppression and the rankings."""
    s = result["setup"]
    methods = result["methods"]
    lines = [
        "# Table II (simulated low-sensing captures): PSNR [dB] (not filtered, filtered), ours vs paper",
        "",
        f"Scene: planar boards (`planar_scene` seed {s['scene_seed']}, depths {list(s['depths'])} m) "
        f"with a cos^4 illumination falloff ({s['fov_deg']:g} deg), {s['size']} x {s['size']} px; "
        f"ground truth: mean of {s['gt_frames']} frames at "
        f"{K.TABLE2_GT_INTEGRATION_TIME * 1e6:g} us; {s['frames']} test frame(s) per "
        "integration time (mean of the dB values). FPN suppression: the paper's {20, 0.14} notch "
        "along the rows + eq. (11) fusion. Denoisers: package defaults, noise k / A from the "
        + (
            "amplitude, k estimated by each denoiser on its input."
            if result.get("noise", "own") == "own"
            else "amplitude, k estimated on the unfiltered frame for both columns."
        ),
        "",
        "| IT | {LOW, IMP} % ours | paper | "
        + " | ".join(f"{LABELS.get(m, m)} ours | paper" for m in ["none", *methods])
        + " |",
        "|---|---|---|" + "---|---|" * (len(methods) + 1),
    ]
    for r in result["rows"]:
        cells = [
            f"{r['integration_time_us']} us",
            f"{{{r['low']:.0f}, {r['imp']:.0f}}}",
            f"{{{r['paper_low']:.0f}, {r['paper_imp']:.0f}}}",
        ]
        for m in ["none", *methods]:
            o = r["psnr"][m]
            p = r["paper"].get(m)
            cells.append(f"({o[0]:.1f}, {o[1]:.1f})")
            cells.append("-" if p is None else f"({p[0]:.1f}, {p[1]:.1f})")
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "## Gain from FPN suppression (filtered - not filtered), dB", ""]
    lines += [
        "| IT | "
        + " | ".join(f"{LABELS.get(m, m)} ours / paper" for m in ["none", *methods])
        + " |",
        "|---|" + "---|" * (len(methods) + 1),
    ]
    for r in result["rows"]:
        cells = [f"{r['integration_time_us']} us"]
        for m in ["none", *methods]:
            o = r["psnr"][m]
            p = r["paper"].get(m)
            pg = "-" if p is None else f"{p[1] - p[0]:+.1f}"
            cells.append(f"{o[1] - o[0]:+.1f} / {pg}")
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "## Ranking by PSNR after FPN suppression (best first)", ""]
    for r in result["rows"]:
        ours = _rank({m: r["psnr"][m][1] for m in methods})
        paper = _rank({m: r["paper"][m][1] for m in methods if m in r["paper"]})
        lines.append(
            f"* {r['integration_time_us']} us: ours {', '.join(ours)}; paper {', '.join(paper)}"
        )
    lines += ["", "## Checks", ""]
    first = result["rows"][0]
    for m in methods:
        o, inp = first["psnr"][m], first["psnr"]["none"]
        lines.append(
            f"* {LABELS.get(m, m)} at {first['integration_time_us']} us: improves on its input "
            f"({o[0]:.2f} vs {inp[0]:.2f} dB not filtered, {o[1]:.2f} vs {inp[1]:.2f} filtered): "
            f"{'yes' if o[0] > inp[0] and o[1] > inp[1] else 'NO'}; gains from FPN suppression: "
            f"{o[1] - o[0]:+.2f} dB ({'yes' if o[1] > o[0] else 'NO'})"
        )
    lines += [
        "",
        f"Ground truth frames saturated: {100 * result['gt_saturated_share']:.2f} %. "
        f"Run time: {result['seconds']:.1f} s.",
    ]
    return "\n".join(lines) + "\n"


TABLE2_CSV_FIELDS = (
    "integration_time_us",
    "method",
    "ours_not_filtered",
    "ours_filtered",
    "ours_gain",
    "paper_not_filtered",
    "paper_filtered",
    "paper_gain",
    "low",
    "imp",
    "paper_low",
    "paper_imp",
)


def _csv_rows(result: dict) -> list[dict]:
    out = []
    for r in result["rows"]:
        for m in ["none", *result["methods"]]:
            o = r["psnr"][m]
            p = r["paper"].get(m) or [None, None]
            out.append(
                {
                    "integration_time_us": r["integration_time_us"],
                    "method": m,
                    "ours_not_filtered": o[0],
                    "ours_filtered": o[1],
                    "ours_gain": o[1] - o[0],
                    "paper_not_filtered": p[0],
                    "paper_filtered": p[1],
                    "paper_gain": None if p[0] is None else p[1] - p[0],
                    "low": r["low"],
                    "imp": r["imp"],
                    "paper_low": r["paper_low"],
                    "paper_imp": r["paper_imp"],
                }
            )
    return out


def plot_table2(result: dict, path: Path) -> Path:
    """Like Fig. 10: the 50 us frame and every denoiser's output, top row without, bottom row
    with FPN suppression (depth colour scale of the ground truth)."""
    plt = pyplot()
    im = result["_images"]
    cols = [*result["methods"], "input"]
    fig, axes = plt.subplots(2, len(cols), figsize=(2.3 * len(cols), 5.0))
    gt = im["gt"]
    lo, hi = float(np.nanpercentile(gt, 1)), float(np.nanpercentile(gt, 99))
    row0 = result["rows"][0]
    for c, name in enumerate(cols):
        for r, suffix in enumerate(("", "_filtered")):
            ax = axes[r, c]
            ax.imshow(im[name + suffix], cmap="viridis", vmin=lo, vmax=hi)
            key = "none" if name == "input" else name
            val = row0["psnr"][key][r]
            title = "noisy input" if name == "input" else LABELS.get(name, name)
            ax.set_title(f"{title}{' + FPN filt.' if r else ''}\n{val:.1f} dB", fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(
        f"IT = {row0['integration_time_us']} us: without (top) and with (bottom) FPN suppression",
        fontsize=9,
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def write_table2(result: dict, out: str | Path) -> dict[str, Path]:
    """table2.csv / .json / .md / .png in ``out`` (the images only in the PNG)."""
    public = {k: v for k, v in result.items() if not k.startswith("_")}
    return write_report(
        out,
        "table2",
        public,
        TABLE2_CSV_FIELDS,
        _csv_rows(result),
        table2_markdown(result),
        lambda _r, p: plot_table2(result, p),
    )
