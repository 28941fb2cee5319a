"""The layout rules of docs/architecture.md, checked on the source (not by eye).

- which package may import which (the run-time layers import torch, kornia, the standard library
  and the constants only; nothing imports upward);
- importing the run-time package loads no SciPy, matplotlib or offline layer;
- no number of the paper written anywhere but ``tof_fpn_torch/constants.py``;
- files over 400 lines and functions over 80 (unless the docstring says why it "cannot be split")
  are reported as a warning (:class:`LayoutWarning`), not failed: files are split by concept, not
  by count, and the list says where a split may be due.
"""

from __future__ import annotations

import ast
import math
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "tof_fpn_torch"
THIRD_PARTY_RUNTIME = {"torch", "kornia"}

#: layer -> layers of the package it may import (besides itself and ``constants``)
ALLOWED: dict[str, set[str]] = {
    "runtime": set(),
    "denoise": {"runtime"},
    "design": {"plotting"},
    "analysis": {"runtime"},
    "sim": {"runtime"},
    "build": {"runtime", "design", "analysis", "denoise", "cameras"},
    "cameras": set(),
    "plotting": set(),
    # the paper's synthetic test data and the demo on it (the reproduction is in benchmarks/)
    "paper_data": {"runtime", "design", "analysis", "denoise", "sim", "build", "cameras"},
    "demo": {"runtime", "design", "analysis", "denoise", "sim", "build", "plotting", "paper_data"},
    "export": {"runtime"},
    "learn": {
        "runtime",
        "build",
        "denoise",
        "analysis",
        "sim",
        "design",
        "cameras",
        "plotting",
        "io",
    },
    # the file layer: beside the simulator (never imports it), reads the validity rule and the
    # camera profile names
    "io": {"runtime", "cameras"},
    # tof-fpn clean: the pipeline over files (docs/clean.md)
    "clean": {"runtime", "build", "denoise", "io", "cameras", "analysis", "plotting"},
    # sim vs. recording (issue 10): reads recordings / scenes, runs the simulator, fits it
    "diagnosis": {
        "runtime",
        "analysis",
        "sim",
        "io",
        "denoise",
        "design",
        "cameras",
        "plotting",
    },
    "cli": {
        "runtime",
        "design",
        "analysis",
        "denoise",
        "sim",
        "build",
        "demo",
        "paper_data",
        "export",
        "plotting",
        "cameras",
        "learn",
        "io",
        "clean",
        "diagnosis",
    },
}
#: third-party packages a layer may import (beyond the standard library)
THIRD_PARTY: dict[str, set[str]] = {
    "runtime": THIRD_PARTY_RUNTIME,
    "denoise": THIRD_PARTY_RUNTIME,
    "design": {"numpy", "scipy"},
    "analysis": THIRD_PARTY_RUNTIME,
    "sim": {"torch"},
    "plotting": {"matplotlib"},
    "cameras": set(),
    "io": {"torch", "numpy", "imageio", "tifffile", "h5py", "av", "PIL", "rosbags"},
    "clean": {"torch", "numpy", "tqdm", "ray", "tomli"},
    "diagnosis": {"torch", "numpy"},
}


def _layer(path: Path) -> str:
    rel = path.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _imports(path: Path) -> list[tuple[str, int]]:
    """Absolute dotted names of every module ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text())
    pkg = ["tof_fpn_torch", *path.relative_to(PACKAGE).parent.parts]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[: len(pkg) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            if node.level and not node.module:  # from .. import constants, x
                out += [(f"{mod}.{alias.name}", node.lineno) for alias in node.names]
            else:
                out.append((mod, node.lineno))
    return out


def _sources() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


@pytest.mark.parametrize("path", _sources(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_follow_the_layers(path):
    layer = _layer(path)
    if layer in ("__init__", "__main__", "constants"):
        return  # the package's lazy index, the CLI entry point, the standard-library constants
    allowed_layers = ALLOWED[layer] | {layer, "constants"}
    bad = []
    for name, line in _imports(path):
        top = name.split(".")[0]
        if top == "tof_fpn_torch":
            parts = name.split(".")
            target = parts[1] if len(parts) > 1 else "__init__"
            if target != "__version__" and target not in allowed_layers:
                bad.append(f"line {line}: {name} (layer {target!r})")
        elif top in sys.stdlib_module_names or top == "__future__":
            continue
        elif layer in THIRD_PARTY and top not in THIRD_PARTY[layer]:
            bad.append(f"line {line}: {name} (third-party {top!r})")
    assert not bad, f"{path.relative_to(PACKAGE)} ({layer}) imports outside its layer: {bad}"


def test_the_rules_see_a_violation(tmp_path):
    """The checker itself: an upward import in a run-time module is reported."""
    fake = PACKAGE / "runtime" / "fpn_filter.py"
    names = [n for n, _ in _imports(fake)]
    assert "tof_fpn_torch.runtime.validity" in names and "torch" in names
    tree_src = "from ..design import design_fpn\nimport numpy as np\nfrom .. import constants\n"
    probe = PACKAGE / "runtime" / "_layout_probe.py"
    try:
        probe.write_text(tree_src)
        names = [n for n, _ in _imports(probe)]
        assert names == ["tof_fpn_torch.design", "numpy", "tof_fpn_torch.constants"]
        with pytest.raises(AssertionError, match="design.*numpy"):
            test_imports_follow_the_layers(probe)
    finally:
        probe.unlink()


def test_importing_the_runtime_loads_no_offline_code():
    code = (
        "import sys, tof_fpn_torch.runtime, tof_fpn_torch.denoise; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('scipy', 'matplotlib') "
        "or m.startswith(('tof_fpn_torch.design', 'tof_fpn_torch.analysis', 'tof_fpn_torch.sim', "
        "'tof_fpn_torch.build', 'tof_fpn_torch.paper_data', 'tof_fpn_torch.demo'))]; print(bad)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=PACKAGE.parent
    )
    assert out.stdout.strip() == "[]", out.stdout


def _paper_numbers() -> tuple[dict[float, str], dict[float, str]]:
    """``(distinctive, defaults)``: the paper's numbers, flagged wherever they appear in code, and
    the package defaults whose values are common (0.2, 20, ...), flagged where they are written as
    a default (a parameter default or an argparse ``default=``). Read from constants.py itself."""
    from tof_fpn_torch import constants as K

    distinctive = {
        abs(float(getattr(K, name))): name
        for name in (
            "CAMCUBE_MODULATION_FREQUENCY_HZ",
            "CAMCUBE_SIZE",
            "SPEED_OF_LIGHT",
            "AIR_REFRACTIVE_INDEX",
            "D_MAX",
            "LOW_SENSING_THRESHOLD",
            "FUSION_HIGH",
            "FPN_ALPHA",
            "FPN_BETA",
            "FPN_GAMMA",
            "MAD_TO_SIGMA",
            "LOG2_E",
        )
    }
    distinctive[2 * math.pi / 3] = "FPN_FREQUENCIES"
    distinctive.update({abs(v): "DB2_DEC_HI" for v in K.DB2_DEC_HI})
    distinctive.update({v: "PAPER_INPUT_PSNR" for v in K.PAPER_INPUT_PSNR.values()})
    for case in K.PAPER_TABLE1.values():
        for row in case.values():
            distinctive.update({v: "PAPER_TABLE1" for v in row})
    for rows in K.PAPER_TABLE2.values():
        distinctive.update({v: "PAPER_TABLE2" for pair in rows for v in pair if v != int(v)})
    defaults = {
        float(getattr(K, name)): name
        for name in (
            "DEFAULT_ORDER",
            "DEFAULT_RHO",
            "FUSION_LOW",
            "FUSION_FLOOR",
            "NLM_AMPLITUDE_FLOOR",
        )
    }
    return distinctive, defaults


def _literals(path: Path) -> list[tuple[float, int, str, bool]]:
    """``(value, line, text, is_default)`` for the numeric literals of the code (docstrings and
    comments are prose, not code) and ``2 * math.pi / 3``-style expressions of the FPN frequency;
    ``is_default``: written as a parameter default or as an argparse ``default=``."""
    tree = ast.parse(path.read_text())
    default_nodes = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.arguments):
            default_nodes.update(id(d) for d in [*node.defaults, *node.kw_defaults] if d)
        elif isinstance(node, ast.keyword) and node.arg == "default":
            default_nodes.add(id(node.value))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and type(node.value) in (int, float):
            is_default = id(node) in default_nodes
            found.append((abs(float(node.value)), node.lineno, repr(node.value), is_default))
        elif isinstance(node, ast.BinOp):
            text = ast.unparse(node).replace(" ", "")
            if text in ("2*math.pi/3", "2.0*math.pi/3.0", "2*np.pi/3", "2*torch.pi/3"):
                found.append((2 * math.pi / 3, node.lineno, text, id(node) in default_nodes))
    return found


def test_paper_numbers_are_written_once():
    distinctive, defaults = _paper_numbers()
    hits = []
    for path in _sources():
        if path.name == "constants.py":
            continue
        for value, line, text, is_default in _literals(path):
            names = [n for ref, n in distinctive.items() if math.isclose(value, ref, rel_tol=1e-12)]
            if is_default:
                names += [
                    n for ref, n in defaults.items() if math.isclose(value, ref, rel_tol=1e-12)
                ]
            if names:
                hits.append(f"{path.relative_to(PACKAGE)}:{line}: {text} is {names[0]}")
    assert not hits, "write these as tof_fpn_torch.constants names:\n" + "\n".join(hits)


def test_the_literal_scan_sees_a_copy(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text(
        '"""D_MAX 7.5 in prose is fine."""\nx = 7.5\nw = 2 * math.pi / 3\n'
        "def f(rho=0.14):\n    return rho * 0.14\n"
    )
    found = _literals(probe)
    assert [v for v, *_ in found].count(7.5) == 1  # the docstring's 7.5 is not code
    assert any(math.isclose(v, 2 * math.pi / 3) for v, *_ in found)
    assert sorted(d for v, _, _, d in found if v == 0.14) == [False, True]  # body / default


#: the length caps: longer files and functions are reported (a warning), not failed
MAX_FILE_LINES = 400
MAX_FUNCTION_LINES = 80


class LayoutWarning(UserWarning):
    """A file or function over its length cap: worth a look, split by concept if one is due."""


def _long_files(paths: list[Path], root: Path = PACKAGE) -> dict[str, int]:
    """``"file" -> lines`` for the files over :data:`MAX_FILE_LINES` lines."""
    out = {}
    for path in paths:
        n = len(path.read_text().splitlines())
        if n > MAX_FILE_LINES:
            out[path.relative_to(root).as_posix()] = n
    return out


def _long_functions(path: Path, root: Path = PACKAGE) -> dict[str, int]:
    """``"file::function" -> lines`` for the functions (and methods) of ``path`` longer than
    :data:`MAX_FUNCTION_LINES` (decorators to the last line) whose docstring does not say why
    they "cannot be split"."""
    tree = ast.parse(path.read_text())
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
            n = node.end_lineno - first + 1
            doc = ast.get_docstring(node) or ""
            if n > MAX_FUNCTION_LINES and "cannot be split" not in " ".join(doc.split()):
                out[f"{path.relative_to(root).as_posix()}::{node.name}"] = n
    return out


def _warn_long(paths: list[Path], root: Path = PACKAGE) -> None:
    """One :class:`LayoutWarning` listing the files and functions over their caps, if any."""
    files = _long_files(paths, root)
    functions: dict[str, int] = {}
    for path in paths:
        functions.update(_long_functions(path, root))
    lines = [f"{k} has {v} lines (cap {MAX_FILE_LINES})" for k, v in sorted(files.items())]
    lines += [f"{k} has {v} lines (cap {MAX_FUNCTION_LINES})" for k, v in sorted(functions.items())]
    if lines:
        warnings.warn(
            LayoutWarning(
                "over the length caps (split by concept if one is due):\n" + "\n".join(lines)
            ),
            stacklevel=2,
        )


def test_long_files_and_functions_are_reported_not_failed():
    """The caps are a warning in the run's summary, never a failure."""
    _warn_long(_sources())


def test_the_length_report_sees_a_long_file(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("x = 1\n" * (MAX_FILE_LINES + 1))
    (tmp_path / "short.py").write_text("x = 1\n" * MAX_FILE_LINES)
    paths = sorted(tmp_path.glob("*.py"))
    assert _long_files(paths, tmp_path) == {"probe.py": MAX_FILE_LINES + 1}
    with pytest.warns(LayoutWarning, match="probe.py has 401 lines \\(cap 400\\)"):
        _warn_long(paths, tmp_path)
    probe.unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _warn_long(sorted(tmp_path.glob("*.py")), tmp_path)  # nothing over: no warning


def test_the_function_length_check_sees_one(tmp_path):
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES))
    probe = tmp_path / "probe.py"
    probe.write_text(
        f'def long():\n{body}\n\ndef kernel():\n    """A TorchScript kernel: it cannot\n'
        f'    be split (one fused loop)."""\n{body}\n\ndef short():\n    return 1\n'
    )
    assert _long_functions(probe, tmp_path) == {"probe.py::long": MAX_FUNCTION_LINES + 1}


def _imported_roots(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module.split(".")[0])
    return out


def test_the_lab_and_the_tests_stay_apart():
    """tests/ never imports the lab beside the package (benchmarks/, examples/: their modules
    have their own tests there); the lab never imports tests/ nor edits sys.path."""
    root = PACKAGE.parent
    lab_dirs = (root / "benchmarks", root / "examples")
    lab = {p.stem for d in lab_dirs for p in d.glob("*.py")} | {"paper"}
    for path in (root / "tests").glob("*.py"):
        assert not (_imported_roots(path) & lab), (path.name, _imported_roots(path) & lab)
    for d in lab_dirs:
        for path in d.rglob("*.py"):
            if "tests" in path.relative_to(d).parts:
                continue
            text = path.read_text()
            assert "sys.path" not in text, path
            assert not (_imported_roots(path) & {"tests", "conftest"}), path
