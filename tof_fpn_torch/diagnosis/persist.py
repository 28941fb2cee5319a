"""The refitted model as a file (``model.json``) that ``--baseline`` loads again.

Content: ``{"content": "tof_fpn_torch.diagnosis_model", "format_version": 1, "camera": {...},
"values": {"owner.field": float}, "effects": [names], "profiles": {"columns": [...], "rows":
[...]}, "frame_interval", "impulsive_level", "fpn_scale", "fitted_camera": {...}, "simulation":
[terms]}``; ``camera`` holds the settings the model was built with (the fitted conversion gain and
read noise are in ``values``); the last two are the fitted camera and the complete simulator chain
(class and fields of every term) for readers, not read back.
"""

from __future__ import annotations

import json
import math
from dataclasses import fields, replace
from pathlib import Path

import torch

from ..sim import Camera
from ..sim import Term as SimTerm
from .catalogue import CATALOGUE
from .incidence import FIELDS_OF_VIEW, FOV_KEY, INCIDENCE_KEY
from .model import CORE_SPECS, DiagnosisModel
from .readout import READOUT_KEYS

__all__ = ["MODEL_CONTENT", "adapt_model", "load_model", "model_to_dict", "save_model"]

MODEL_CONTENT = "tof_fpn_torch.diagnosis_model"
MODEL_VERSION = 1


def _plain(x):
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().double().tolist()
    if isinstance(x, SimTerm):  # a part of a Joined stage (two forms of one effect)
        return _term_dict(x)
    if isinstance(x, (tuple, list)):
        return [_plain(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def model_to_dict(model: DiagnosisModel) -> dict:
    """The model as JSON data."""
    sim = model.simulation()
    return {
        "content": MODEL_CONTENT,
        "format_version": MODEL_VERSION,
        "camera": {k: _plain(v) for k, v in model.camera.as_dict().items()},
        "fitted_camera": {k: _plain(v) for k, v in model.simulation_camera().as_dict().items()},
        "values": {k: float(v) for k, v in sorted(model.values.items())},
        "effects": list(model.effects),
        "profiles": {k: _plain(v) for k, v in model.profiles.items()},
        "frame_interval": model.frame_interval,
        "impulsive_level": model.impulsive_level,
        "fpn_scale": model.fpn_scale,
        "fixed": sorted(model.fixed),
        "random_columns": model.random_columns,
        "simulation": [_term_dict(t) for t in sim.terms],
    }


def _term_dict(t) -> dict:
    """A simulator term as JSON data: its class, name and fields."""
    return {
        "term": type(t).__name__,
        "name": t.name,
        **{f.name: _plain(getattr(t, f.name)) for f in fields(t) if f.name != "name"},
    }


def save_model(model: DiagnosisModel, path) -> Path:
    """Write ``model.json`` (sorted keys; the same model gives the same bytes)."""
    p = Path(path)
    p.write_text(json.dumps(model_to_dict(model), indent=1, sort_keys=True) + "\n")
    return p


def load_model(source) -> DiagnosisModel:
    """A :class:`DiagnosisModel` from a ``model.json`` path or its dict; ``ValueError`` names
    what is wrong."""
    if isinstance(source, dict):
        data, where = source, "model"
    else:
        p = Path(source)
        if not p.is_file():
            raise FileNotFoundError(f"baseline model file not found: {p}")
        try:
            data = json.loads(p.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{p}: not a model.json (invalid JSON: {exc})") from exc
        where = str(p)
    if not isinstance(data, dict) or data.get("content") != MODEL_CONTENT:
        raise ValueError(f"{where}: not a diagnosis model (content must be {MODEL_CONTENT!r})")
    if data.get("format_version") != MODEL_VERSION:
        raise ValueError(f"{where}: format_version {data.get('format_version')!r} is not 1")
    for key in ("camera", "values", "effects"):
        if key not in data:
            raise ValueError(f"{where}: missing key {key!r}")
    try:
        cam = Camera(**data["camera"])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: bad camera: {exc}") from exc
    effects = list(data["effects"])
    bad = [e for e in effects if e not in CATALOGUE or not CATALOGUE[e].implemented]
    if bad:
        raise ValueError(f"{where}: unknown effects {bad}; known: {sorted(CATALOGUE)}")
    values = {k: float(v) for k, v in data["values"].items()}
    values.setdefault("camera.ambient_irradiance", float(cam.ambient_irradiance))
    values.setdefault(INCIDENCE_KEY, 0.0)  # a model saved before the baseline held the angle
    values.setdefault(FOV_KEY, FIELDS_OF_VIEW[len(FIELDS_OF_VIEW) // 2])
    need = [s.key for s in CORE_SPECS] + [s.key for e in effects for s in CATALOGUE[e].specs]
    missing = [k for k in need if k not in values]
    if missing:
        raise ValueError(f"{where}: values lack {missing}")
    nonfinite = [k for k in need if not math.isfinite(values[k])]
    if nonfinite:
        raise ValueError(f"{where}: values {nonfinite} are not finite")
    profiles = {
        k: torch.tensor(v, dtype=torch.float64) for k, v in (data.get("profiles") or {}).items()
    }
    return DiagnosisModel(
        cam,
        values,
        [CATALOGUE[e] for e in effects],
        profiles,
        float(data.get("frame_interval", 1.0)),
        float(data.get("impulsive_level", 1e-6)),
        float(data.get("fpn_scale", 1.0)),
        frozenset(data.get("fixed", ())),
        bool(data.get("random_columns", False)),
    )


def adapt_model(model: DiagnosisModel, obs) -> DiagnosisModel:
    """Check that a loaded model fits ``obs`` (profile lengths) and take the recording's
    modulation frequency and phase count where it states them."""
    h, w = obs.shape
    for key, n, what in (("columns", w, "columns"), ("rows", h, "rows")):
        prof = model.profiles.get(key)
        if prof is not None and prof.numel() != n:
            raise ValueError(
                f"baseline model's {key} profile has {prof.numel()} entries, the recording "
                f"{n} {what}: the model was fitted to frames of another size"
            )
    prof = model.profiles.get("frame_delays")
    if prof is not None and prof.numel() != obs.frames:
        raise ValueError(
            f"baseline model's per-frame drift has {prof.numel()} frames, the recording "
            f"{obs.frames}: the model was fitted to another recording's frames"
        )
    for key in READOUT_KEYS:
        prof = model.profiles.get(key)
        if prof is not None and prof.shape[-1] != w:
            raise ValueError(
                f"baseline model's read-out columns have {prof.shape[-1]} entries, the "
                f"recording {w} columns: the model was fitted to frames of another size"
            )
    m = model.copy()
    cam = m.camera
    if obs.frequency is not None:
        cam = replace(cam, modulation_frequency=obs.frequency)
    m.camera = replace(cam, n_phases=obs.n_phases, integration_time=obs.integration_time)
    return m
