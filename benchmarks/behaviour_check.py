"""Behaviour unchanged: a fixed set of ``tof-fpn`` runs whose outputs must keep their bytes.

Use it around a change that must not change behaviour (a refactor)::

    python benchmarks/behaviour_check.py run /tmp/behaviour_after   # ~100 s of CPU, one thread
    python benchmarks/behaviour_check.py compare benchmarks/behaviour_reference.json \\
        /tmp/behaviour_after/behaviour.json

``compare`` prints every difference (a file missing or extra, a hash that differs, a line of a
command's output that differs) and exits 1 if there is any, 0 if the two are identical.
``benchmarks/behaviour_reference.json`` is the reference written by ``run`` on the code before
the change. A change that is meant to keep behaviour must compare identical; every difference it
does give must be listed, with its reason, where the change is described (an exported
TorchScript archive, for instance, holds the module's scripted code and its module path, so it
changes when that code is reorganised, while its outputs, also compared, must not). Re-record the reference only for a
change that is meant to change behaviour, and say so.

``run OUTDIR`` writes, with fixed seeds and one thread everywhere:

* ``OUTDIR/inputs/``: the inputs, made here with NumPy and the package's file writers;
  ``adi/wall_depth.png`` + ``adi/wall_amplitude.png`` (the real ADI ADTF3175 wall capture of
  ``tests/data/real`` as a uint16-mm PNG pair), ``mkv/desk_recording.mkv`` (the real Azure
  Kinect recording, copied), ``striped/`` (six PNG pairs with a shared column pattern and depth
  edges, a multi-frame TIFF pair and a multi-frame HDF5 file with a moving object) and
  ``diagnose/`` (a simulated recording with a cyclic error, and its scene);
* one folder per command, each run as a user runs it, ``python -m tof_fpn_torch ...`` in a
  subprocess with ``OUTDIR`` as the working folder (relative paths):

  - ``demo``: ``tof-fpn demo --out demo --threads 1``
  - ``clean_adi``: ``tof-fpn clean inputs/adi clean_adi`` (the default stage)
  - ``clean_mkv``: ``tof-fpn clean inputs/mkv clean_mkv``
  - ``clean_striped``: ``tof-fpn clean inputs/striped clean_striped --denoise nlm
    --flying invalidate --temporal``
  - ``diagnose``: ``tof-fpn diagnose inputs/diagnose/rec.npz --scene inputs/diagnose/scene.npz``
  - ``export_torchscript``, ``export_onnx``: ``tof-fpn export --format torchscript`` / ``onnx``

* ``OUTDIR/behaviour.json``: for every input and output file its path relative to ``OUTDIR``
  and the SHA-256 of its bytes. JSON, JSONL and TOML files are normalised first (keys holding
  times, durations, dates, run ids, host names, versions and file times dropped; absolute paths
  masked, floats to 12 significant digits; everything else kept) and their normalised content
  is stored; Markdown and text files are stored with times masked. ``.npz`` archives get a hash
  per member too, so a difference names the array. Exported TorchScript / ONNX models are
  hashed without their debug information (source paths and line numbers) and loaded
  (``torch.jit.load``, ``onnxruntime``) to hash their output on a fixed seeded input too. Each
  command's standard output is stored line by line with times, rates, versions and paths
  masked (the printed stage line and summary are behaviour too). Nothing stored depends on
  where the checkout or ``OUTDIR`` is. ``meta`` (versions of the libraries, commit, wall time)
  is shown by ``compare`` but never counts as a difference.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
from real_captures import REAL_DATA_DIR

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
REAL = REAL_DATA_DIR
FORMAT = 1  # of behaviour.json

# --- normalising manifests and reports ----------------------------------------------------------

#: keys dropped from JSON / JSONL / TOML before hashing (matched on the key's own name)
VOLATILE_KEYS = re.compile(
    r"^(time|times|timestamp|date|datetime|created_at|started|finished|start_time|end_time|"
    r"elapsed|duration|seconds|wall|wall_time|eta|run|run_id|pid|host|hostname|node|user|"
    r"version|versions|python|torch_version|numpy_version|mtime|mtime_ns|ctime|atime)$"
    r"|_(s|ms|us|ns|sec|secs|seconds|time_s|wall|wall_s|elapsed|duration)$",
    re.IGNORECASE,
)
#: keys that match VOLATILE_KEYS by their form but hold values (kept)
KEPT_KEYS = frozenset({"timestamps_s", "integration_time_s", "exposure_s", "period_s", "frame_s"})

#: significant digits of the floats of normalised JSON / TOML: some values the stage measures on
#: the data (e.g. the manifest's ``pipeline.stripe_scale``) differ in their last binary digit from
#: one run of the same command to the next, while every output byte stays the same
FLOAT_DIGITS = 12

_ABS_PATH = re.compile(r"(?<![\w.\-<>])/(?:[\w.\-+@~]+/)*[\w.\-+@~]+")
_MASKS = [
    # dates and clock times
    (
        re.compile(r"\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}(?::\d{2}(?:\.\d+)?)?(?:Z|[+-]\d{2}:?\d{2})?"),
        "<date>",
    ),
    (re.compile(r"\b\d{1,2}:\d{2}(?::\d{2}(?:\.\d+)?)?\b"), "<clock>"),
    # rates and durations
    (re.compile(r"\b\d+(?:\.\d+)?(?:e[+-]?\d+)?\s?(?:frames|files|it|MB|px)/s\b"), "<rate>"),
    (
        re.compile(r"(?<![\w.])\d+(?:\.\d+)?(?:e[+-]?\d+)?\s?(?:s|ms|us|µs|min|h|sec|seconds)\b"),
        "<time>",
    ),
]


def mask_text(text: str, replacements: dict[str, str] | None = None) -> list[str]:
    """``text`` as lines with the known folders replaced (``replacements``: literal -> mark),
    other absolute paths, dates, clock times, rates and durations masked; trailing spaces and
    carriage-return progress overwrites removed."""
    for literal, mark in sorted((replacements or {}).items(), key=lambda kv: -len(kv[0])):
        if literal:
            text = text.replace(literal, mark)
    lines = text.replace("\r\n", "\n").split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    out = []
    for line in lines:
        line = line.rsplit("\r", 1)[-1]  # a progress bar redrawn in place: its last state
        line = _ABS_PATH.sub("<path>", line)
        for pattern, mark in _MASKS:
            line = pattern.sub(mark, line)
        out.append(line.rstrip())
    return out


def normalise(obj, replacements: dict[str, str] | None = None, _path: str = ""):
    """``(normalised, dropped)``: ``obj`` (parsed JSON / TOML) without the keys holding times,
    durations, dates, run ids, hosts and versions, with absolute paths in strings masked and
    floats rounded to :data:`FLOAT_DIGITS` significant digits; ``dropped`` lists the dotted paths
    of the keys removed (lists as ``[]``)."""
    dropped: list[str] = []
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            p = f"{_path}.{k}" if _path else str(k)
            if str(k) not in KEPT_KEYS and VOLATILE_KEYS.search(str(k)):
                dropped.append(p)
                continue
            out[k], d = normalise(v, replacements, p)
            dropped += d
        return out, dropped
    if isinstance(obj, list):
        out = []
        for v in obj:
            n, d = normalise(v, replacements, f"{_path}[]")
            out.append(n)
            dropped += d
        return out, sorted(set(dropped))
    if isinstance(obj, str):
        s = obj
        for literal, mark in sorted((replacements or {}).items(), key=lambda kv: -len(kv[0])):
            if literal:
                s = s.replace(literal, mark)
        return _ABS_PATH.sub("<path>", s), dropped
    if isinstance(obj, float):
        if not np.isfinite(obj):
            return repr(obj), dropped  # NaN / inf: JSON has no literal for them
        return float(f"{obj:.{FLOAT_DIGITS}g}"), dropped
    return obj, dropped


def _canonical(obj) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


# --- one file's entry ---------------------------------------------------------------------------

_TEXT = (".md", ".txt", ".csv", ".log")


def describe(path: Path, replacements: dict[str, str] | None = None) -> dict:
    """The entry of one file: its kind, the SHA-256 of its bytes and what is compared."""
    data = path.read_bytes()
    entry: dict = {"bytes": len(data), "sha256": sha256(data)}
    suffix = path.suffix.lower()
    if suffix in (".json", ".jsonl", ".toml"):
        text = data.decode()
        if suffix == ".json":
            parsed = json.loads(text)
        elif suffix == ".jsonl":
            parsed = [json.loads(line) for line in text.splitlines() if line.strip()]
        else:
            parsed = tomllib.loads(text)
        content, dropped = normalise(parsed, replacements)
        entry.update(
            kind=suffix[1:],
            compare="normalised_sha256",
            normalised_sha256=sha256(_canonical(content)),
            dropped=sorted(set(dropped)),
            content=content,
        )
    elif suffix in _TEXT:
        lines = mask_text(data.decode(), replacements)
        entry.update(
            kind="text",
            compare="normalised_sha256",
            normalised_sha256=sha256("\n".join(lines).encode()),
            content=lines,
        )
    elif suffix == ".pt":
        members = torchscript_members(data, replacements)
        entry.update(
            kind="torchscript",
            compare="normalised_sha256",
            normalised_sha256=sha256(_canonical(members)),
            members=members,
        )
    elif suffix == ".onnx":
        entry.update(
            kind="onnx", compare="normalised_sha256", **onnx_normalised(data, replacements)
        )
    elif suffix == ".npz":
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            members = {i.filename: sha256(zf.read(i)) for i in zf.infolist()}
        entry.update(kind="npz", compare="sha256", members=members)
    else:
        entry.update(kind=suffix[1:] or "file", compare="sha256")
    return entry


# --- exported models: the archive without its debug information, the outputs on a fixed input ---


def _mask_bytes(data: bytes, replacements: dict[str, str] | None) -> bytes:
    for literal, mark in sorted((replacements or {}).items(), key=lambda kv: -len(kv[0])):
        if literal:
            data = data.replace(literal.encode(), mark.encode())
    return data


def torchscript_members(data: bytes, replacements: dict[str, str] | None = None) -> dict:
    """SHA-256 of each member of a TorchScript archive (the scripted code, the constants, the
    tensors), the debug information left out: its ``*.debug_pkl`` hold the source file's
    absolute path and line numbers, and ``.data/serialization_id`` is derived from all members.
    The code is compared as scripted, so it changes when the module's code does."""
    out = {}
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        for info in zf.infolist():
            name = info.filename.split("/", 1)[-1]  # without the archive's own folder name
            if name.endswith(".debug_pkl") or name == ".data/serialization_id":
                continue
            out[name] = sha256(_mask_bytes(zf.read(info), replacements))
    return out


def _canonical_names(graph) -> None:
    """Rename the nodes (``n0``, ``n1``, ... in graph order) and the values between them (``v0``,
    ``v1``, ... in order of first use) of ``graph``, the graph's inputs and outputs kept: the
    exporter numbers them from a counter that shifts when code traced before them changes."""
    keep = {v.name for v in graph.input} | {v.name for v in graph.output} | {""}
    names: dict[str, str] = {}

    def new(name: str) -> str:
        if name in keep:
            return name
        if name not in names:
            names[name] = f"v{len(names)}"
        return names[name]

    for i, node in enumerate(graph.node):
        node.name = f"n{i}"
        node.input[:] = [new(x) for x in node.input]
        node.output[:] = [new(x) for x in node.output]
    for group in (graph.initializer, graph.value_info):
        items = sorted(group, key=lambda v: new(v.name))
        for item in items:
            item.name = new(item.name)
        copies = [type(item)() for item in items]
        for c, item in zip(copies, items, strict=True):
            c.CopyFrom(item)
        del group[:]
        group.extend(copies)


def onnx_normalised(data: bytes, replacements: dict[str, str] | None = None) -> dict:
    """The hash of an ONNX model without what the exporter records for debugging (each node's
    ``doc_string`` and ``metadata_props``: stack traces with file paths and line numbers, FX
    node text) and without the producer's version, nodes and intermediate values renamed by
    their place in the graph; the graph, its initialisers and the model's own
    ``metadata_props`` (the stage's parameters) are kept. ``ops``: the node count per
    operator type, to read a difference."""
    import onnx

    model = onnx.load_from_string(data)

    def strip(graph) -> None:
        for node in graph.node:
            node.doc_string = ""
            del node.metadata_props[:]
            for attr in node.attribute:
                if attr.type == onnx.AttributeProto.GRAPH:
                    strip(attr.g)
                for g in attr.graphs:
                    strip(g)

    strip(model.graph)
    _canonical_names(model.graph)
    for fn in model.functions:
        for node in fn.node:
            node.doc_string = ""
            del node.metadata_props[:]
    model.producer_version = ""
    ops: dict[str, int] = {}
    for node in model.graph.node:
        ops[node.op_type] = ops.get(node.op_type, 0) + 1
    blob = _mask_bytes(model.SerializeToString(deterministic=True), replacements)
    return {"normalised_sha256": sha256(blob), "ops": dict(sorted(ops.items()))}


def model_input(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """depth (2, 1, 48, 64) float32 metres (frame 0 with column stripes at pi and 2 pi / 3, frame
    1 without; a few NaN) and amplitude (counts from 20 to 600, across the fusion thresholds)."""
    rng = np.random.default_rng(seed)
    h, w = 48, 64
    x = np.arange(w)
    plane = 1.5 + 0.4 * np.linspace(0, 1, h)[:, None] + 0.002 * x[None, :]
    stripes = 0.01 * np.cos(np.pi * x) + 0.006 * np.cos(2 * np.pi / 3 * x)
    depth = np.stack([plane + stripes[None], plane]) + 0.002 * rng.standard_normal((2, h, w))
    depth[rng.random((2, h, w)) < 0.01] = np.nan
    amplitude = rng.uniform(20, 600, (2, h, w))
    return depth[:, None].astype(np.float32), amplitude[:, None].astype(np.float32)


def _outputs_entry(outputs) -> dict:
    out = []
    for y in outputs:
        y = np.ascontiguousarray(np.asarray(y))
        finite = np.isfinite(y)
        out.append(
            {
                "shape": list(y.shape),
                "dtype": str(y.dtype),
                "sha256": sha256(y.tobytes()),
                "nonfinite": int((~finite).sum()),
                "mean": float(y[finite].mean()) if finite.any() else None,
            }
        )
    return {"input": "model_input(seed=0): depth, amplitude (2, 1, 48, 64)", "outputs": out}


def torchscript_outputs(path: Path) -> dict:
    import torch

    torch.set_num_threads(1)
    model = torch.jit.load(str(path), map_location="cpu").eval()
    depth, amplitude = model_input()
    with torch.no_grad():
        y = model(torch.from_numpy(depth), torch.from_numpy(amplitude))
    ys = y if isinstance(y, (tuple, list)) else [y]
    return _outputs_entry([t.numpy() for t in ys])


def onnx_outputs(path: Path) -> dict:
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    depth, amplitude = model_input()
    feeds = dict(zip([i.name for i in sess.get_inputs()], (depth, amplitude), strict=True))
    return _outputs_entry(sess.run(None, feeds))


# --- the inputs ---------------------------------------------------------------------------------


def _real(rel: str) -> Path:
    p = REAL / rel
    if not p.is_file():
        raise SystemExit(f"real capture missing: {p} (tests/data/real of the repository)")
    return p


def make_adi(folder: Path) -> None:
    """The ADI ADTF3175 wall (raw uint16 LE 512 x 512, depth mm with 0 invalid, active IR) as the
    PNG pair a user has: ``wall_depth.png`` + ``wall_amplitude.png``, the same integers."""
    from tof_fpn_torch import io as tio

    folder.mkdir(parents=True)
    depth = np.fromfile(_real("adi_adtf3175/wall_depth_u16le_512x512.bin"), "<u2")
    ir = np.fromfile(_real("adi_adtf3175/wall_ir_u16le_512x512.bin"), "<u2")
    depth, ir = depth.reshape(512, 512), ir.reshape(512, 512)
    metres = np.where(depth > 0, depth.astype(np.float64) * 1e-3, np.nan).astype(np.float32)
    tio.write_pair(
        folder / "wall_depth.png", metres, ir.astype(np.float32), folder / "wall_amplitude.png"
    )
    # the pair holds exactly the capture's integers
    import imageio.v3 as iio

    assert np.array_equal(iio.imread(folder / "wall_depth.png"), depth)
    assert np.array_equal(iio.imread(folder / "wall_amplitude.png"), ir)


def make_mkv(folder: Path) -> None:
    folder.mkdir(parents=True)
    shutil.copyfile(_real("azure_kinect/desk_recording.mkv"), folder / "desk_recording.mkv")


def _striped_scene(rng, h: int, w: int, col: np.ndarray, box: tuple[int, int, int, int] | None):
    """Depth (metres) of a slanted wall, with a box in front (mixed pixels on its edge) unless
    ``box`` is None, plus the shared column pattern ``col`` (metres), noise of sd 0.02 / A m and
    a few invalid pixels; amplitude (counts) rising from 30 to 180 across the frame."""
    yy, xx = np.mgrid[0:h, 0:w]
    wall = 1.6 + 0.3 * yy / h + 0.2 * xx / w
    amplitude = (30.0 + 150.0 * xx / w) * (1 + 0.1 * rng.random((h, w)))
    depth = wall
    if box is not None:
        y0, y1, x0, x1 = box
        inside = (yy >= y0) & (yy < y1) & (xx >= x0) & (xx < x1)
        core = (yy >= y0 + 1) & (yy < y1 - 1) & (xx >= x0 + 1) & (xx < x1 - 1)
        mix = rng.uniform(0.2, 0.8, (h, w))
        depth = np.where(core, 0.9, np.where(inside, mix * 0.9 + (1 - mix) * wall, wall))
    depth = depth + col[None, :] + 0.02 / amplitude * rng.standard_normal((h, w))
    depth[rng.random((h, w)) < 0.01] = np.nan
    return depth.astype(np.float32), np.rint(amplitude).astype(np.float32)


def make_striped(folder: Path, seed: int = 0) -> None:
    """Six uint16-mm PNG pairs 48 x 64 (``f0_depth.png`` + ``f0_amplitude.png`` ...), a 10-frame
    TIFF pair (``take_depth.tif`` + ``take_amplitude.tif``) and an 8-frame HDF5 file
    (``walk.h5``), all with one column pattern (stripes at pi and 2 pi / 3 plus broadband
    offsets): three of the pairs a bare wall, the others a box in front of it with flying pixels
    on its edge; in the multi-frame files the box stands still for five frames, then moves."""
    from tof_fpn_torch import io as tio

    folder.mkdir(parents=True)
    rng = np.random.default_rng(seed)
    h, w = 48, 64
    x = np.arange(w)
    col = 0.004 * np.cos(np.pi * x) + 0.003 * np.cos(2 * np.pi / 3 * x) + rng.normal(0, 0.0015, w)
    for i in range(6):
        box = (12, 28, 12 + 2 * i, 28 + 2 * i) if i < 3 else None
        d, a = _striped_scene(rng, h, w, col, box)
        tio.write_pair(folder / f"f{i}_depth.png", d, a, folder / f"f{i}_amplitude.png")
    for name, frames, step in (("take", 10, 2), ("walk", 8, 3)):
        shift = [step * max(t - 4, 0) for t in range(frames)]
        pairs = [_striped_scene(rng, h, w, col, (14, 30, 8 + s, 24 + s)) for s in shift]
        d = np.stack([p[0] for p in pairs])
        a = np.stack([p[1] for p in pairs])
        if name == "take":
            tio.write_pair(folder / "take_depth.tif", d, a, folder / "take_amplitude.tif")
        else:
            tio.write_pair(folder / "walk.h5", d, a)


def make_diagnose(folder: Path) -> None:
    """A simulated recording (40 x 56 px, 10 frames) with a 6 % third-harmonic cyclic error the
    baseline lacks, and its scene, as docs/diagnosis.md writes them."""
    import torch

    from tof_fpn_torch.io import (
        recording_from_simulation,
        scene_from_sim,
        write_recording,
        write_scene,
    )
    from tof_fpn_torch.sim import Camera, Simulation, synthetic_scene
    from tof_fpn_torch.sim.effects import CyclicError, with_effect

    folder.mkdir(parents=True)
    torch.set_num_threads(1)
    scene = synthetic_scene(40, 56, seed=1, depth_range=(0.6, 5.0))
    camera = Camera(integration_time=300e-6, adc_bits=16)
    sim = with_effect(Simulation(camera), CyclicError(cos_terms=(0.06, 0.0)))
    out = sim.run(scene, frames=10, seed=1)
    write_recording(folder / "rec.npz", recording_from_simulation(out, camera))
    write_scene(folder / "scene.npz", scene_from_sim(scene))


INPUTS = {"adi": make_adi, "mkv": make_mkv, "striped": make_striped, "diagnose": make_diagnose}

#: name -> the tof-fpn arguments, run with OUTDIR as the working folder; the output folder is
#: ``name`` (the export files under ``export/``)
RUNS: dict[str, list[str]] = {
    "demo": ["demo", "--out", "demo", "--threads", "1"],
    "clean_adi": ["clean", "inputs/adi", "clean_adi", "--threads", "1", "--quiet"],
    "clean_mkv": ["clean", "inputs/mkv", "clean_mkv", "--threads", "1", "--quiet"],
    "clean_striped": [
        "clean",
        "inputs/striped",
        "clean_striped",
        "--denoise",
        "nlm",
        "--flying",
        "invalidate",
        "--temporal",
        "--threads",
        "1",
        "--quiet",
    ],
    "diagnose": [
        "diagnose",
        "inputs/diagnose/rec.npz",
        "--scene",
        "inputs/diagnose/scene.npz",
        "--out",
        "diagnose",
        "--threads",
        "1",
    ],
    "export_torchscript": [
        "export",
        "--format",
        "torchscript",
        "--out",
        "export/fpn_suppression.pt",
    ],
    "export_onnx": ["export", "--format", "onnx", "--out", "export/fpn_suppression.onnx"],
}


# --- run ----------------------------------------------------------------------------------------


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    env.update(
        OMP_NUM_THREADS="1",
        MKL_NUM_THREADS="1",
        OPENBLAS_NUM_THREADS="1",
        MPLBACKEND="Agg",
        PYTHONHASHSEED="0",
        TZ="UTC",
        COLUMNS="100",
    )
    env.pop("RAY_ADDRESS", None)
    return env


def _meta(wall_s: float, run_s: dict[str, float]) -> dict:
    from importlib import metadata

    versions = {}
    for name in (
        "torch",
        "numpy",
        "onnx",
        "onnxruntime",
        "onnxscript",
        "matplotlib",
        "pillow",
        "imageio",
        "tifffile",
        "h5py",
        "scipy",
    ):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    git = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True
    )
    dirty = subprocess.run(
        ["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
        capture_output=True,
        text=True,
    )
    return {
        "python": sys.version.split()[0],
        "versions": versions,
        "commit": git.stdout.strip() or None,
        "dirty": bool(dirty.stdout.strip()),
        "wall_s": round(wall_s, 1),
        "run_s": {k: round(v, 1) for k, v in run_s.items()},
    }


def run(outdir: Path) -> dict:
    """Make the inputs, run every command, describe every file; write OUTDIR/behaviour.json."""
    t0 = time.perf_counter()
    outdir = outdir.resolve()
    if outdir.exists() and any(outdir.iterdir()):
        raise SystemExit(f"{outdir} is not empty: give a new or empty folder")
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / "export").mkdir()
    for name, maker in INPUTS.items():
        maker(outdir / "inputs" / name)
    env = _env()
    version = subprocess.run(
        [sys.executable, "-m", "tof_fpn_torch", "--version"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()[-1]
    replacements = {str(outdir): "<OUT>", str(ROOT): "<REPO>", sys.prefix: "<PREFIX>"}
    text_replacements = {**replacements, version: "<version>"}
    commands, run_s = {}, {}
    for name, args in RUNS.items():
        print(f"[{name}] tof-fpn {' '.join(args)}", flush=True)
        t = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "tof_fpn_torch", *args],
            cwd=outdir,
            env=env,
            capture_output=True,
            text=True,
            stdin=subprocess.DEVNULL,
        )
        run_s[name] = time.perf_counter() - t
        if proc.returncode != 0:
            sys.stderr.write(proc.stdout + proc.stderr)
            raise SystemExit(f"[{name}] exited with {proc.returncode}")
        commands[name] = {
            "argv": ["tof-fpn", *args],
            "returncode": proc.returncode,
            "stdout": mask_text(proc.stdout, text_replacements),
        }
        print(f"[{name}] {run_s[name]:.1f} s", flush=True)
    inputs, outputs = {}, {}
    for p in sorted(outdir.rglob("*")):
        rel = p.relative_to(outdir).as_posix()
        if not p.is_file() or rel == "behaviour.json":
            continue
        entry = describe(p, replacements)
        if rel.startswith("inputs/"):
            inputs[rel] = entry
            continue
        if p.suffix == ".pt":
            entry["model"] = torchscript_outputs(p)
        elif p.suffix == ".onnx":
            entry["model"] = onnx_outputs(p)
        outputs[rel] = entry
    result = {
        "format": FORMAT,
        "commands": commands,
        "inputs": inputs,
        "outputs": outputs,
        "meta": _meta(time.perf_counter() - t0, run_s),
    }
    (outdir / "behaviour.json").write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    return result


# --- compare ------------------------------------------------------------------------------------


def _content_diff(a, b, path: str = "") -> list[str]:
    """Where two normalised contents differ (dotted key paths, list indices), at most a few."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b), key=str):
            p = f"{path}.{k}" if path else str(k)
            if k not in b:
                out.append(f"{p}: only in A")
            elif k not in a:
                out.append(f"{p}: only in B")
            else:
                out += _content_diff(a[k], b[k], p)
        return out
    if isinstance(a, list) and isinstance(b, list):
        out = []
        if len(a) != len(b):
            out.append(f"{path}: {len(a)} items in A, {len(b)} in B")
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            out += _content_diff(x, y, f"{path}[{i}]")
        return out
    if a != b:
        return [f"{path}: {json.dumps(a)[:120]} -> {json.dumps(b)[:120]}"]
    return []


def _file_diffs(section: str, a: dict, b: dict) -> list[str]:
    out = []
    for rel in sorted(set(a) | set(b)):
        if rel not in b:
            out.append(f"{section} {rel}: missing in B")
            continue
        if rel not in a:
            out.append(f"{section} {rel}: extra in B")
            continue
        ea, eb = a[rel], b[rel]
        key = ea.get("compare", "sha256")
        if key != eb.get("compare", "sha256") or ea.get(key) != eb.get(key):
            what = {
                "torchscript": "archive (debug information aside)",
                "onnx": "model graph (debug information aside)",
            }.get(ea.get("kind"), "normalised content" if key == "normalised_sha256" else "bytes")
            out.append(f"{section} {rel}: {what} hash differs")
            if "content" in ea and "content" in eb:
                details = _content_diff(ea["content"], eb["content"])
                out += [f"    {d}" for d in details[:20]]
                if len(details) > 20:
                    out.append(f"    ... {len(details) - 20} more")
            ma, mb = ea.get("members", {}), eb.get("members", {})
            for m in sorted(set(ma) | set(mb)):
                if ma.get(m) != mb.get(m):
                    out.append(f"    member {m} differs")
            oa, ob = ea.get("ops", {}), eb.get("ops", {})
            for op in sorted(set(oa) | set(ob)):
                if oa.get(op) != ob.get(op):
                    out.append(f"    {op} nodes: {oa.get(op, 0)} -> {ob.get(op, 0)}")
            if "model" in ea and ea.get("model") == eb.get("model"):
                out.append("    (the model's outputs on the fixed input are identical)")
        if ea.get("model") != eb.get("model"):
            out.append(f"{section} {rel}: model outputs on the fixed input differ")
            for i, (ya, yb) in enumerate(
                zip(
                    ea.get("model", {}).get("outputs", []),
                    eb.get("model", {}).get("outputs", []),
                    strict=False,
                )
            ):
                if ya != yb:
                    out.append(f"    output {i}: {ya} -> {yb}")
    return out


def compare(a: dict, b: dict) -> list[str]:
    """Every difference between two behaviour records (A: reference, B: new), one line each
    (indented lines detail the line above); empty when identical. ``meta`` is not compared."""
    diffs: list[str] = []
    if a.get("format") != b.get("format"):
        diffs.append(f"format {a.get('format')} -> {b.get('format')}")
    ca, cb = a.get("commands", {}), b.get("commands", {})
    for name in sorted(set(ca) | set(cb)):
        if name not in cb:
            diffs.append(f"command {name}: missing in B")
            continue
        if name not in ca:
            diffs.append(f"command {name}: extra in B")
            continue
        x, y = ca[name], cb[name]
        for key in ("argv", "returncode"):
            if x.get(key) != y.get(key):
                diffs.append(f"command {name}: {key} {x.get(key)} -> {y.get(key)}")
        la, lb = x.get("stdout", []), y.get("stdout", [])
        for i in range(max(len(la), len(lb))):
            u = la[i] if i < len(la) else "<no line>"
            v = lb[i] if i < len(lb) else "<no line>"
            if u != v:
                diffs.append(f"command {name}: stdout line {i + 1} differs")
                diffs.append(f"    A: {u}")
                diffs.append(f"    B: {v}")
    diffs += _file_diffs("input", a.get("inputs", {}), b.get("inputs", {}))
    diffs += _file_diffs("output", a.get("outputs", {}), b.get("outputs", {}))
    return diffs


def _versions_note(a: dict, b: dict) -> list[str]:
    va = a.get("meta", {}).get("versions", {})
    vb = b.get("meta", {}).get("versions", {})
    return [
        f"note: {k} {va.get(k)} -> {vb.get(k)}"
        for k in sorted(set(va) | set(vb))
        if va.get(k) != vb.get(k)
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the fixed set into OUTDIR; write OUTDIR/behaviour.json")
    r.add_argument("outdir", type=Path)
    c = sub.add_parser("compare", help="print every difference; exit 1 if any")
    c.add_argument("a", type=Path, help="reference behaviour.json")
    c.add_argument("b", type=Path, help="new behaviour.json")
    args = ap.parse_args(argv)
    if args.cmd == "run":
        res = run(args.outdir)
        n = len(res["outputs"])
        print(f"wrote {args.outdir}/behaviour.json: {n} output files, {res['meta']['wall_s']} s")
        return 0
    a = json.loads(args.a.read_text())
    b = json.loads(args.b.read_text())
    for line in _versions_note(a, b):
        print(line)
    diffs = compare(a, b)
    for line in diffs:
        print(line)
    if diffs:
        n = sum(not d.startswith(" ") for d in diffs)
        print(f"{n} difference(s)")
        return 1
    print(
        f"identical: {len(a.get('commands', {}))} commands, {len(a.get('outputs', {}))} output files"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
