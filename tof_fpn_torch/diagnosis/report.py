"""The diagnosis as files: ``report.json``, ``report.md``, figures and ``model.json``.

Everything is rendered in memory first and written into a temporary folder beside the output,
which is then moved into place; an error before that leaves nothing behind."""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path

from .naming import FORM_TOLERANCE
from .persist import model_to_dict
from .summary import OWN_SHARE

__all__ = ["confidence_text", "markdown", "render", "write_outputs"]

_FILES = ("report.json", "report.md", "model.json")


def _num(x, digits: int = 4) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        if not math.isfinite(x):
            return str(x)
        return f"{x:.{digits}g}"
    return str(x)


def _where_text(w: dict) -> str:
    parts = [f"`{w['statistic']}` ({w['excess_sigma']} sigma above its null, p = {w['p']:.2g})"]
    if "spectrum" in w:
        sp = w["spectrum"]
        near = sp["excess_power_share_near"]
        parts.append(
            f"{sp['verdict']}: half the excess power in {sp['bins_holding_half_the_excess_power']}"
            f" of {sp['frequency_bins']} frequency bins; share near 2pi/3 {near['2pi/3']:.0%}, "
            f"near pi {near['pi']:.0%}; profile rms {w['profile_rms']:.3g} {w['profile_unit']}"
        )
    for r in w.get("ranges", [])[:3]:
        parts.append(
            f"{r['from']:.4g}..{r['to']:.4g} {r['unit']}: "
            + (
                f"{r['mean_residual']:.3g}"
                if "sd" in r["residual_unit"]
                else f"{r['mean_residual']:+.3g}"
            )
            + f" {r['residual_unit']} ({r['pixels']} px)"
        )
    if "frames_beyond_3_sigma" in w:
        parts.append(f"frames beyond 3 sigma: {w['frames_beyond_3_sigma'][:10]}")
    if "share_beyond_4_sigma" in w:
        parts.append(
            f"{w['share_beyond_4_sigma']:.2%} of pixels beyond 4 sigma, dispersion "
            f"{w['dispersion_ratio']}x the null"
        )
    if "expected" in w:
        parts.append(f"count {w['value']:.0f}, expected {w['expected']}")
    if "after" in w:
        a = w["after"]
        inside = "inside" if a["inside_null_band"] else "still outside"
        parts.append(f"after: p = {a['p']:.2g}, {inside} its null band")
    return "; ".join(parts)


def markdown(report: dict, figures: list[str]) -> str:
    """The Markdown report."""
    lines = ["# Diagnosis: simulation vs. recording", ""]
    rec = report["recording"]
    lines.append(
        f"Recording: {rec['frames']} frame(s) of {rec['height']}x{rec['width']} px; "
        f"{rec['depth_pixels']} pixels in the depth likelihood, {rec['amplitude_pixels']} in "
        f"the amplitude likelihood; scene {'estimated from the recording' if rec['scene_estimated'] else 'given'}; "
        f"{report['bootstrap_replicates']} bootstrap recordings per null; {report['seconds']} s."
    )
    for n in rec["notes"]:
        lines.append(f"- {n}")
    base = report.get("baseline")
    if base and (base["terms"] or base["random_columns"]):
        held = [
            f"`{t}`" + (" (stated)" if any(k.startswith(t + ".") for k in base["stated"]) else "")
            for t in base["terms"]
        ]
        if base["random_columns"]:
            rc = base["readout_random_columns"]
            held.append(
                f"random read-out columns ({rc['offset_rms_dn']:.3g} DN offsets, "
                f"{rc['gain_rms']:.3g} gains rms)"
            )
        lines.append(f"- the baseline holds: {', '.join(held)}")
    lines += ["", f"**Verdict: {', '.join(report['verdict'])}**", ""]
    conf = report.get("confidence")
    if conf:
        lines += [f"Confidence: {confidence_text(conf)}.", ""]
    lines += _effects_md(report)
    fb, fa = report["fit"]["before"], report["fit"]["after"]
    lines += ["## Fit before / after", "", "| | before | after |", "|---|---|---|"]
    for key, label in (
        ("heldout_nll", "held-out NLL (nats)"),
        ("heldout_nll_per_observation", "held-out NLL per observation"),
        ("aic", "AIC (all pixels)"),
        ("parameters", "parameters"),
        ("residual_rms_depth_mm", "residual RMS, depth temporal mean (mm)"),
        ("residual_rms_amplitude_percent", "residual RMS, amplitude temporal mean (%)"),
    ):
        lines.append(f"| {label} | {_num(fb[key], 8)} | {_num(fa[key], 8)} |")
    lines.append("")
    if report.get("held_back"):
        lines += ["## Unexplained: structure no single term explains", ""]
        for h in report["held_back"]:
            terms = ", ".join(f"`{t}`" for t in h["terms"])
            lines.append(
                f"- stood in for by {terms} (held-out gain {_num(h['score'])} nats), not named: "
                f"it removes less than {OWN_SHARE:.0%} of any structure on its axes that is "
                "there without it"
            )
            for w in h["structure"][:3]:
                lines.append(f"  - {_where_text(w)}")
        lines.append("")
    if report["unexplained"]:
        lines += ["## Significant residual no catalogue term explains", ""]
        for w in report["unexplained"][:6]:
            lines.append(f"- {_where_text(w)}")
        lines.append("")
    lines += ["## Located statistics before (baseline)", ""]
    if report["located_before"]:
        for w in report["located_before"][:10]:
            lines.append(f"- {_where_text(w)}")
    else:
        lines.append("- none significant")
    lines += [
        "",
        "## Candidates (first round)",
        "",
        "| term | held-out gain | delta AIC | k | significant |",
        "|---|---|---|---|---|",
    ]
    for c in report["candidates"][0] if report["candidates"] else []:
        lines.append(
            f"| `{c['name']}` | {_num(c['score'])} | {_num(c['delta_aic'])} | "
            f"{_num(c['added_parameters'])} | {'yes' if c['significant'] else 'no'} |"
        )
    lines += ["", f"Not implemented: {', '.join(report['not_implemented'])}.", ""]
    for f in figures:
        lines += [f"![{f}]({f})", ""]
    return "\n".join(lines)


def confidence_text(conf: dict) -> str:
    """The verdict's confidence in words (``report["confidence"]``)."""
    out = conf["level"]
    why = []
    if conf.get("runner_up") is not None and conf.get("runner_up_share") is not None:
        why.append(
            f"runner-up `{conf['runner_up']}` gains {conf['runner_up_share']:.0%} as much in the "
            "first round"
        )
    if "explains_its_structure" in conf:
        why.append(
            "its located structure is explained"
            if conf["explains_its_structure"]
            else "its located structure is not explained"
        )
    left = conf.get("residual_statistics") or []
    if left:
        why.append(f"{len(left)} statistic(s) still significant after the refit")
    if conf.get("held_back"):
        why.append("held back as unexplained: " + ", ".join(f"`{h}`" for h in conf["held_back"]))
    if "best_candidate_gain" in conf:
        why.append(f"best candidate gains {conf['best_candidate_gain']:.4g} nats")
    return out + (f" ({'; '.join(why)})" if why else "")


def render(diag, with_figures: bool = True) -> dict[str, bytes]:
    """Every output file of a diagnosis as ``{name: bytes}`` (nothing written)."""
    from .figures import figures

    figs = figures(diag) if with_figures else {}
    out = {
        "report.json": (
            json.dumps(diag.report, indent=1, sort_keys=True, default=float) + "\n"
        ).encode(),
        "model.json": (
            json.dumps(model_to_dict(diag.model), indent=1, sort_keys=True) + "\n"
        ).encode(),
        "report.md": markdown(diag.report, list(figs)).encode(),
    }
    out.update(figs)
    return out


def write_outputs(files: dict[str, bytes], out_dir) -> list[str]:
    """Write ``files`` into ``out_dir`` (created if needed) all or nothing; returns the paths."""
    out = Path(out_dir)
    parent = out.parent if str(out.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)
    try:
        for name, data in files.items():
            (tmp / name).write_bytes(data)
        if not out.exists():
            os.replace(tmp, out)
        else:
            for name in files:
                os.replace(tmp / name, out / name)
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [os.path.join(str(out_dir), n) for n in files]


def _effects_md(report: dict) -> list[str]:
    """The effects named: the table (effect, form, gain, AIC, parameters), what else is
    consistent, and where each was located."""
    lines: list[str] = []
    if report["effects"]:
        lines += [
            "| effect | form (terms) | held-out gain (nats) | delta AIC | parameters |",
            "|---|---|---|---|---|",
        ]
        for e in report["effects"]:
            ps = ", ".join(f"{k} = {_num(v)}" for k, v in e["params"].items())
            forms = ", ".join(f"`{t}`" for t in e.get("terms", [e["name"]]))
            lines.append(
                f"| `{e['name']}` | {forms} | {_num(e['score'])} | {_num(e['delta_aic'])} | {ps} |"
            )
        lines.append("")
        also = report.get("also_consistent_with") or []
        if also:
            lines += [
                "Also consistent with (significant on their own, not beyond the effects named: "
                "below a refit of their other forms, or within what a misfit of their form "
                f"leaves, {FORM_TOLERANCE:g} of their held-out gain): "
                + ", ".join(f"`{a}`" for a in also),
                "",
            ]
        for e in report["effects"]:
            lines.append(f"### `{e['name']}`: the evidence (where it was located)")
            for w in e["where"]:
                lines.append(f"- {_where_text(w)}")
            lines.append("")
    else:
        lines += ["No catalogue term improves the held-out likelihood significantly.", ""]
    return lines
