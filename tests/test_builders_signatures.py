"""The builders' signatures and the package's top-level names, checked on the source.

- no function in ``tof_fpn_torch/build/`` takes ``**kwargs``: every option is an explicit keyword
  parameter, and every parameter of a public builder is documented in its docstring's ``Args:``;
- the builders refuse a bad option up front with a ``ValueError`` naming it and what is allowed;
- ``tof_fpn_torch/__init__.py`` imports, under ``TYPE_CHECKING``, exactly the names its lazy
  ``__getattr__`` serves, from the modules it serves them from (so type checkers and IDEs see
  what the runtime gives), and mypy resolves them.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import tof_fpn_torch
from tof_fpn_torch import build

PACKAGE = Path(tof_fpn_torch.__file__).resolve().parent
BUILD = PACKAGE / "build"


# --- no **kwargs in build/ --------------------------------------------------------------------


def _var_keyword_functions(path: Path) -> list[str]:
    """``"function (line)"`` for every function or lambda of ``path`` with a ``**`` parameter."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            if node.args.kwarg is not None:
                out.append(f"{getattr(node, 'name', 'lambda')} (line {node.lineno})")
    return out


def test_no_function_in_build_takes_var_keyword_arguments():
    paths = sorted(BUILD.rglob("*.py"))
    assert {p.name for p in paths} >= {"__init__.py", "data.py", "design.py"}
    found = {str(p.relative_to(PACKAGE)): _var_keyword_functions(p) for p in paths}
    bad = {k: v for k, v in found.items() if v}
    assert not bad, f"give these functions explicit keyword parameters: {bad}"


def test_the_var_keyword_check_sees_one(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text(
        "def explicit(a, *, b=1):\n    return a\n\n"
        "def hidden(a, **kwargs):\n    return a\n\n"
        "class C:\n    def method(self, **options):\n        return f(lambda **kw: kw)\n"
    )
    assert _var_keyword_functions(probe) == [
        "hidden (line 4)",
        "method (line 8)",
        "lambda (line 9)",
    ]


# --- every builder parameter documented --------------------------------------------------------


def _documented(doc: str) -> set[str]:
    """The names of the ``Args:`` section of a (dedented) Google-style docstring; an entry may
    name several (``depth, amplitude: ...``)."""
    lines = doc.splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == "Args:")
    except StopIteration:
        return set()
    indent = len(lines[start]) - len(lines[start].lstrip())
    names: set[str] = set()
    entry = re.compile(r"^\s*([A-Za-z_]\w*(?:\s*,\s*[A-Za-z_]\w*)*)\s*:(\s|$)")
    item_indent = None
    for line in lines[start + 1 :]:
        if not line.strip():
            continue
        here = len(line) - len(line.lstrip())
        if here <= indent:
            break  # the next section
        item_indent = here if item_indent is None else item_indent
        if here == item_indent:
            m = entry.match(line)
            assert m, f"not an Args entry: {line!r}"
            names |= {n.strip() for n in m.group(1).split(",")}
    return names


def _builders() -> dict[str, object]:
    return {
        name: getattr(build, name)
        for name in build.__all__
        if inspect.isfunction(getattr(build, name))
    }


def test_the_builders_are_found():
    assert set(_builders()) == {
        "broadband_from_data",
        "filter_from_design",
        "fusion_from_data",
        "fusion_from_noise",
        "suppression_from_data",
        "suppression_from_design",
        "trainable_suppression",
    }


@pytest.mark.parametrize("name", sorted(_builders()))
def test_every_builder_parameter_is_documented(name):
    func = _builders()[name]
    params = set(inspect.signature(func).parameters)
    documented = _documented(inspect.getdoc(func) or "")
    assert params - documented == set(), f"{name}: parameters missing from Args"
    assert documented - params == set(), f"{name}: Args names no parameter"


def test_the_docstring_check_sees_a_missing_and_a_stale_entry():
    def probe(depth, amplitude, order=1, *, rho=0.1, floor=0.2):
        """Probe.

        Args:
            depth, amplitude: frames.
            order: the order
                (continued: ``not_a_name: here``).
            gone: a parameter that is no more.
            floor: the floor.

        Raises:
            ValueError: never.
        """

    assert _documented(inspect.getdoc(probe)) == {"depth", "amplitude", "order", "gone", "floor"}
    assert _documented("No sections.") == set()


# --- the keywords callers pass are accepted, bad values refused up front ----------------------

#: the keys ``tof_fpn_torch/clean/pipeline.py`` passes the stage builders through a dict
PIPELINE_KEYWORDS = (
    "adaptive",
    "camera",
    "low",
    "high",
    "floor",
    "destripe",
    "order",
    "rho",
    "gate",
)


@pytest.mark.parametrize("builder", ["suppression_from_design", "suppression_from_data"])
def test_the_pipelines_keywords_are_parameters(builder):
    params = inspect.signature(getattr(build, builder)).parameters
    keys = PIPELINE_KEYWORDS + (("camera_hint",) if builder == "suppression_from_data" else ())
    assert set(keys) <= set(params)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: build.filter_from_design(border="mirror"), r"border must be one of .*'mirror'"),
        (lambda: build.filter_from_design(dim=0), r"dim must be -1 .*got 0"),
        (lambda: build.filter_from_design(unit_dc="yes"), r"unit_dc must be True or False"),
        (lambda: build.filter_from_design(max_ripple_db="x"), r"max_ripple_db must be a finite"),
        (lambda: build.suppression_from_design(camera="nikon"), r"unknown camera profile 'nikon'"),
        (lambda: build.suppression_from_design(floor=2.0), r"floor must be .*\[0, 1\].*2\.0"),
        (lambda: build.suppression_from_design(gate=None), r"gate must be True or False"),
        (lambda: build.suppression_from_design(destripe=3), r"destripe must be an nn.Module"),
        (lambda: build.trainable_suppression(low=-1.0), r"low must be .*\[0, inf\].*-1\.0"),
        (lambda: build.broadband_from_data(_FRAMES, width=2), r"width must be an int >= 3.*2"),
        (lambda: build.fusion_from_noise(_FRAMES, _FRAMES, floor=-0.5), r"floor must be"),
        (lambda: build.fusion_from_data(_FRAMES, _FRAMES, filter=3), r"filter must be an FPNF"),
    ],
)
def test_bad_options_are_refused_with_what_is_allowed(call, match):
    with pytest.raises(ValueError, match=match):
        call()


_FRAMES = torch.ones(1, 1, 8, 8)


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"order": 2.5}, r"order must be an integer in \[1, 1024\], got 2\.5"),
        ({"rho": -0.1}, r"rho must be .*\(0, inf\].*-0\.1"),
        ({"estimate_kwargs": {"smoth": 4}}, r"unknown keys \['smoth'\]; allowed: \['orient"),
        ({"destripe": "on"}, r"destripe must be 'auto', None or an nn.Module, got 'on'"),
        ({"adaptive": 1}, r"adaptive must be True or False, got 1"),
        ({"camera_hint": 5}, r"camera_hint must be a camera profile's name or None"),
        ({"border": "wrap"}, r"border must be one of"),
        ({"high": float("nan")}, r"high must be a finite"),
    ],
)
def test_suppression_from_data_checks_before_estimating(monkeypatch, options, match):
    """The options are checked before the stripes are estimated (which would take the time)."""

    def no_estimate(*args, **kwargs):
        raise AssertionError("estimated before the options were checked")

    monkeypatch.setattr("tof_fpn_torch.build.data.estimate_stripes", no_estimate)
    with pytest.raises(ValueError, match=match):
        build.suppression_from_data(_FRAMES, _FRAMES, **options)


# --- the top-level names, visible to type checkers ---------------------------------------------


def _init_tables() -> tuple[dict, dict, tuple]:
    """``_EXPORTS``, ``_MODULES`` and ``_SUBPACKAGES`` as written in ``__init__.py``."""
    tables = {}
    for node in ast.parse((PACKAGE / "__init__.py").read_text()).body:
        target = node.target if isinstance(node, ast.AnnAssign) else None
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target = node.targets[0]
        if isinstance(target, ast.Name) and target.id in ("_EXPORTS", "_MODULES", "_SUBPACKAGES"):
            tables[target.id] = ast.literal_eval(node.value)
    return tables["_EXPORTS"], tables["_MODULES"], tables["_SUBPACKAGES"]


def _type_checking_imports(source: str) -> dict[str, str]:
    """``name -> module`` (relative to the package, ``""`` for the package itself) of the
    imports under ``if TYPE_CHECKING:``; each must be an explicit re-export (``X as X``) and
    appear once."""
    blocks = [
        node
        for node in ast.parse(source).body
        if isinstance(node, ast.If)
        and isinstance(node.test, ast.Name)
        and node.test.id == "TYPE_CHECKING"
    ]
    assert len(blocks) == 1, "one `if TYPE_CHECKING:` block at the top level"
    out: dict[str, str] = {}
    for node in blocks[0].body:
        assert isinstance(node, ast.ImportFrom) and node.level == 1, ast.unparse(node)
        for alias in node.names:
            assert alias.asname == alias.name, f"{ast.unparse(node)}: write `X as X`"
            assert alias.name not in out, f"{alias.name} imported twice"
            out[alias.name] = node.module or ""
    return out


def _expected_imports() -> dict[str, str]:
    """``name -> module`` the lazy tables serve: ``_EXPORTS``, ``_MODULES`` (a submodule, imported
    from its parent), ``_SUBPACKAGES`` (from the package)."""
    exports, modules, subpackages = _init_tables()
    expected = dict(exports)
    for name, path in modules.items():
        parent, _, leaf = path.rpartition(".")
        assert leaf == name, f"_MODULES[{name!r}] = {path!r}: the name is its last component"
        expected[name] = parent
    for name in subpackages:
        expected[name] = ""
    return expected


def _drift(found: dict[str, str]) -> dict[str, tuple[str | None, str | None]]:
    """``name -> (imported from, served from)`` where they disagree. A name may be imported from
    a submodule of the module that serves it (``runtime.destripe`` for ``runtime``'s
    ``destripe``, which type checkers would take for the submodule)."""
    expected = _expected_imports()
    out: dict[str, tuple[str | None, str | None]] = {}
    for name in sorted(set(found) | set(expected)):
        got, want = found.get(name), expected.get(name)
        if (
            got is None
            or want is None
            or not (got == want or (want and got.startswith(want + ".")))
        ):
            out[name] = (got, want)
    return out


def test_type_checking_imports_are_the_lazy_names():
    found = _type_checking_imports((PACKAGE / "__init__.py").read_text())
    assert _drift(found) == {}
    assert sorted(found) == sorted(n for n in tof_fpn_torch.__all__ if n != "__version__")


@pytest.mark.parametrize(
    ("line", "drifted"),
    [
        ("    from .runtime import FPNFilter as FPNFilter\n", ""),  # a name left out
        (
            "    from .runtime import FPNFilter as FPNFilter\n",
            "    from .runtime import FPNFilter as FPNFilter\n    from .io import extra as extra\n",
        ),  # a name the runtime does not serve
        (
            "    from .runtime.destripe import destripe as destripe\n",
            "    from .runtimes import destripe as destripe\n",
        ),  # not a submodule of runtime
        (
            "    from .runtime import FPNFilter as FPNFilter\n",
            "    from .design import FPNFilter as FPNFilter\n",  # from another module
        ),
        ("    from .sim import Scene as Scene\n", "    from .sim import Scene as Scene\n" * 2),
        ("    from . import io as io\n", "    from . import io\n"),  # not a re-export
    ],
)
def test_the_type_checking_check_sees_a_drift(line, drifted):
    source = (PACKAGE / "__init__.py").read_text()
    assert line in source
    try:
        found = _type_checking_imports(source.replace(line, drifted))
    except AssertionError:
        return  # refused: imported twice, or not written as a re-export
    assert _drift(found) != {}


def test_the_lazy_names_are_defined_where_they_are_imported_from():
    exports, modules, subpackages = _init_tables()
    for name, module in exports.items():
        mod = importlib.import_module(f"tof_fpn_torch.{module}")
        assert getattr(mod, name) is getattr(tof_fpn_torch, name), name
    for name, path in modules.items():
        assert getattr(tof_fpn_torch, name) is importlib.import_module(f"tof_fpn_torch.{path}")
    for name in subpackages:
        here = PACKAGE / name
        assert (here / "__init__.py").is_file() or here.with_suffix(".py").is_file(), name


def test_mypy_sees_the_top_level_names(tmp_path):
    """mypy (a test dependency) resolves the lazy names through the ``TYPE_CHECKING`` imports:
    without them it reveals ``Any`` (the module ``__getattr__`` is all it sees)."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import tof_fpn_torch\n"
        "reveal_type(tof_fpn_torch.FPNSuppression)\n"
        "reveal_type(tof_fpn_torch.suppression_from_design)\n"
        "reveal_type(tof_fpn_torch.destripe)\n"
    )
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            "--follow-imports=silent",
            "--ignore-missing-imports",
            "--cache-dir",
            str(tmp_path / "cache"),
            str(probe),
        ],
        capture_output=True,
        text=True,
        cwd=PACKAGE.parent,
        env={**os.environ, "MYPYPATH": str(PACKAGE.parent)},
    )
    revealed = re.findall(r'Revealed type is "(.*)"', out.stdout)
    assert len(revealed) == 3, out.stdout + out.stderr
    assert revealed[0].endswith("-> tof_fpn_torch.runtime.suppression.FPNSuppression"), revealed
    assert "camera: str | None" in revealed[1] and "**" not in revealed[1], revealed
    assert revealed[2].startswith("def (depth:"), revealed  # the function, not the submodule
