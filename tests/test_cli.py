"""The ``tof-fpn`` command line: errors, output paths, defaults, --version, README examples.

Every CLI run here is quick (small scenes, ``--quick``, or an error before any work); the ONNX
export itself is exercised in ``tests/test_export.py``.
"""

from __future__ import annotations

import importlib.util
import inspect
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import real_capture

import tof_fpn_torch
from tof_fpn_torch import constants as K
from tof_fpn_torch import export as X
from tof_fpn_torch.cli import _common, build_parser, main
from tof_fpn_torch.cli import demo as cli_demo
from tof_fpn_torch.cli import design as cli_design
from tof_fpn_torch.cli import export as cli_export
from tof_fpn_torch.demo import run_demo
from tof_fpn_torch.design import MAX_ORDER, RemezConvergenceError, max_rho
from tof_fpn_torch.paper_data import make_synthetic_data

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    """Run in an empty temporary directory (relative output paths land there)."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


def run(argv, capsys):
    """``main(argv)`` -> (exit status, stdout, stderr lines)."""
    status = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return status, cap.out, cap.err.strip().splitlines()


def one_line_error(command, argv, capsys):
    """Run, expect exit 2 with exactly one ``tof-fpn <command>: error: ...`` line; return it."""
    status, out, err = run(argv, capsys)
    assert status == 2, (argv, out, err)
    assert len(err) == 1, err
    prefix = f"tof-fpn {command}: error: " if command else "tof-fpn: error: "
    assert err[0].startswith(prefix), err[0]
    return err[0]


# --- 1. design --order 100000 ----------------------------------------------------------------


def test_design_huge_order_is_one_line_error(cwd, capsys):
    line = one_line_error(
        "design", ["design", "--order", "100000", "--rho", "0.1", "--out", "t.npy"], capsys
    )
    assert "order=100000" in line and f"<= {MAX_ORDER}" in line
    assert list(cwd.iterdir()) == []


# --- 9. every bad argument: one line naming the argument, the value and what is allowed -------

FIVE_NOTCHES = ["--notch", "0.1", "--notch", "0.2", "--notch", "0.3", "--notch", "0.4"]
D = ["design", "--out", "t.npy"]

BAD = [
    # design
    (D + ["--order", "x", "--rho", "0.1"], ["--order", "'x'", "int"]),
    (D + ["--order", "2", "--rho", "0.1"], ["order=2", ">= 3"]),
    (D + ["--order", "20", "--rho", "0"], ["--rho", "'0'", "> 0"]),
    (D + ["--order", "20", "--rho", "nan"], ["--rho", "'nan'", "finite"]),
    (D + ["--order", "20", "--rho", "0.9"], ["--rho 0.9", f"{max_rho():.6g}"]),
    (D + ["--order", "20", "--rho", "0.1", *FIVE_NOTCHES], ["--rho 0.1", "(0, 0.0159155]"]),
    (D + ["--order", "20", "--rho", "0.1", "--notch", "4"], ["--notch", "'4'", "(0, pi]"]),
    (D + ["--order", "20", "--rho", "0.1", "--notch", "abc"], ["--notch", "'abc'", "2pi/3"]),
    (D + ["--order", "20", "--rho", "0.1", "--notch", "pi", "--notch", "pi"], ["distinct"]),
    (D + ["--order", "20", "--rho", "0.1", "--band-weight", "-1"], ["--band-weight", "'-1'"]),
    (D + ["--order", "20", "--rho", "0.1", "--band-weight", "1"], ["band_weights", "2 finite"]),
    (["design", "--rho", "0.1", "--out", "t.npy"], ["required", "--order"]),
    # export
    (["export", "--format", "tflite"], ["--format", "'tflite'", "torchscript"]),
    (["export", "--format", "onnx", "--opset", "13"], ["opset must be an int >= 17, got 13"]),
    (["export", "--format", "onnx", "--opset", "99"], ["--opset", "99", f"[{X.MIN_OPSET}, "]),
    (["export", "--format", "torchscript", "--opset", "18"], ["--opset 18", "onnx only"]),
    (["export", "--format", "torchscript", "--dim", "x"], ["--dim", "'x'", "columns"]),
    (["export", "--format", "torchscript", "--order", "2000"], ["order=2000", f"{MAX_ORDER}"]),
    (["export", "--format", "torchscript", "--rho", "0.5"], ["--rho 0.5", f"{max_rho():.6g}"]),
    # demo
    (["demo", "--dpi", "5"], ["dpi", "5", "[10, 600]"]),
    (["demo", "--dpi", "x"], ["--dpi", "'x'"]),
    (["demo", "--seed", "-1"], ["--seed", "'-1'", ">= 0"]),
    (["demo", "--size", "8"], ["--size", "'8'", "[32, 4096]"]),
    (["demo", "--order", "2"], ["order", "2", ">= 3"]),
    (["demo", "--rho", "0.5"], ["rho", "0.5", f"{max_rho():.6g}"]),
    (["demo", "--threads", "0"], ["--threads", "'0'"]),
    # top level
    ([], ["required", "COMMAND"]),
    (["bogus"], ["'bogus'", "design"]),
]


@pytest.mark.parametrize("argv, needles", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_argument_is_one_line_error(argv, needles, cwd, capsys):
    command = argv[0] if argv and argv[0] in ("design", "export", "demo") else ""
    line = one_line_error(command, argv, capsys)
    for needle in needles:
        assert needle in line, (needle, line)
    assert list(cwd.iterdir()) == []  # nothing written, no directory created


def test_design_that_does_not_converge_is_one_line_error(cwd, capsys, monkeypatch):
    def fail(*args, **kwargs):
        raise RemezConvergenceError("Remez exchange did not converge in 100 iterations")

    monkeypatch.setattr(cli_design, "design_fpn", fail)
    line = one_line_error(
        "design", ["design", "--order", "20", "--rho", "1e-9", "--out", "t.npy"], capsys
    )
    assert "--order 20 --rho 1e-09" in line and "did not converge" in line


def test_float_and_int_arg_messages():
    with pytest.raises(Exception, match=r"must be an int in \[1, 4\], got '5'"):
        _common.int_arg(1, 4)("5")
    with pytest.raises(Exception, match=r"must be a finite number > 0, got 'inf'"):
        _common.float_arg(0.0, open_lo=True)("inf")
    assert _common.int_arg(1)("7") == 7 and _common.float_arg(0.0)("0") == 0.0


def test_cli_bounds_agree_with_the_library():
    """MIN_SIZE is the paper data's own lower bound on the scene side (not a second opinion)."""
    make_synthetic_data((0,), _common.MIN_SIZE)
    with pytest.raises(ValueError, match="size"):
        make_synthetic_data((0,), _common.MIN_SIZE - 1)


# --- 2. output paths: the file written is exactly the path printed ---------------------------


def test_design_refuses_a_suffix_numpy_would_change(cwd, capsys):
    line = one_line_error(
        "design", ["design", "--order", "20", "--rho", "0.1", "--out", "x.txt"], capsys
    )
    assert "--out" in line and "'x.txt'" in line and ".npy" in line
    assert list(cwd.iterdir()) == []  # neither x.txt nor x.txt.npy


def test_design_refuses_a_plot_without_an_image_suffix(cwd, capsys):
    argv = ["design", "--order", "20", "--rho", "0.1", "--out", "t.npy", "--plot", "resp"]
    line = one_line_error("design", argv, capsys)
    assert "--plot" in line and "'resp'" in line and ".png" in line
    assert list(cwd.iterdir()) == []  # matplotlib would have written resp.png


def test_design_writes_exactly_the_paths_it_prints(cwd, capsys):
    out, plot = "./new//taps.NPY", "figs/resp.PNG"  # np.save(path) would write taps.NPY.npy
    status, text, err = run(
        ["design", "--order", "20", "--rho", "0.1", "--out", out, "--plot", plot], capsys
    )
    assert status == 0, err
    assert f"taps written to : {out}\n" in text and f"response plot   : {plot}\n" in text
    assert "created directory ./new\n" in text and "created directory figs\n" in text
    assert sorted(p.name for p in (cwd / "new").iterdir()) == ["taps.NPY"]
    assert sorted(p.name for p in (cwd / "figs").iterdir()) == ["resp.PNG"]
    with open(out, "rb") as fh:
        assert np.load(fh).shape == (21,)
    status, text, _ = run(
        ["design", "--order", "20", "--rho", "0.1", "--out", out, "--json"], capsys
    )
    report = json.loads(text)
    assert status == 0 and report["out"] == out and report["created"] == []


def test_export_writes_exactly_the_path_it_prints(cwd, capsys):
    status, text, err = run(["export", "--format", "torchscript", "--out", "sub/model"], capsys)
    assert status == 0, err
    report = json.loads(text)
    assert report["out"] == "sub/model" and report["created"] == ["sub"]
    assert os.listdir("sub") == ["model"]
    torch.jit.load("sub/model")


def test_demo_prints_the_files_it_wrote(cwd, capsys):
    status, text, err = run(["demo", "--size", "32", "--out", "./d1/"], capsys)
    assert status == 0, err
    assert "picture: ./d1/demo.png " in text and "wrote ./d1/demo.png, ./d1/demo.json\n" in text
    assert sorted(os.listdir("d1")) == ["demo.json", "demo.png"]


# --- 6. output directories: created ones are reported, impossible ones refused ---------------


def test_existing_directory_is_not_reported_as_created(cwd, capsys):
    (cwd / "old").mkdir()
    status, text, _ = run(["demo", "--size", "32", "--out", "old"], capsys)
    assert status == 0 and "created directory" not in text


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["design", "--order", "20", "--rho", "0.1", "--out", "f/t.npy"], "'f' is a file"),
        (["design", "--order", "20", "--rho", "0.1", "--out", "d"], "end in .npy"),
        (["design", "--order", "20", "--rho", "0.1", "--out", "d.npy"], "directory 'd.npy'"),
        (["export", "--format", "torchscript", "--out", "f/x/m.pt"], "'f' is a file"),
        (["export", "--format", "torchscript", "--out", "d"], "directory 'd'"),
        (["demo", "--out", "f"], "'f' is a file"),
        (["demo", "--out", ""], "--out must be a directory path"),
    ],
)
def test_impossible_output_paths_are_refused(argv, needle, cwd, capsys):
    (cwd / "f").write_text("a file")
    (cwd / "d").mkdir()
    (cwd / "d.npy").mkdir()
    line = one_line_error(argv[0], argv, capsys)
    assert needle in line and "--out" in line
    assert sorted(p.name for p in cwd.iterdir()) == ["d", "d.npy", "f"]


def test_unwritable_directory_is_refused(cwd, capsys, monkeypatch):
    monkeypatch.setattr(_common.os, "access", lambda path, mode: False)
    line = one_line_error("demo", ["demo", "--out", "x/y"], capsys)
    assert "--out 'x/y'" in line and "not writable" in line


def test_failed_run_removes_the_directories_it_created(cwd, capsys):
    one_line_error("demo", ["demo", "--out", "a/b/c", "--dpi", "5"], capsys)
    assert list(cwd.iterdir()) == []


def test_file_system_errors_are_one_line(cwd, capsys, monkeypatch):
    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", "t.npy")

    monkeypatch.setattr(cli_design.np, "save", refuse)
    status, _, err = run(["design", "--order", "20", "--rho", "0.1", "--out", "t.npy"], capsys)
    assert status == 1 and len(err) == 1
    assert err[0].startswith("tof-fpn design: error: ") and "Permission denied" in err[0]


# --- 4. ONNX extra ----------------------------------------------------------------------------


def test_onnx_missing_gives_the_install_hint(cwd, capsys, monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a, **k: None if name in ("onnx", "onnxscript") else real(name, *a, **k),
    )
    line = one_line_error("export", ["export", "--format", "onnx"], capsys)
    assert 'pip install "tof_fpn_torch[onnx]"' in line and "onnxscript" in line
    assert list(cwd.iterdir()) == []


def test_pyproject_has_the_onnx_extra():
    tomllib = pytest.importorskip("tomllib")
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    names = {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0] for r in extras["onnx"]}
    assert {"onnx", "onnxscript"} <= names


def _fake_export_onnx(written_opset=None):
    """A stand-in for export_onnx (the real one takes ~8 s): a tiny valid model at ``path``."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    def fake(module, path, opset=18, **kwargs):
        x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])
        y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])
        graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g", [x], [y])
        ops = [helper.make_opsetid("", written_opset or opset)]
        onnx.save(helper.make_model(graph, opset_imports=ops), str(path))
        return Path(path)

    return fake


def test_export_reports_the_opset_written(cwd, capsys, monkeypatch):
    pytest.importorskip("onnxscript")
    monkeypatch.setattr(X, "export_onnx", _fake_export_onnx(written_opset=18))
    status, text, err = run(["export", "--format", "onnx", "--opset", "20"], capsys)
    assert status == 0
    assert json.loads(text)["opset"] == 18 and os.listdir() == ["fpn_suppression.onnx"]
    assert len(err) == 1 and "warning" in err[0] and "--opset 20" in err[0] and "18" in err[0]


# --- export report: the module's own attributes -----------------------------------------------


def test_export_report_describes_the_module_written(cwd, capsys):
    argv = ["export", "--format", "torchscript", "--out", "m.pt", "--order", "21", "--rho", "0.1"]
    argv += ["--notch", "pi", "--notch", "2pi/3", "--dim", "both", "--no-adaptive"]
    status, text, err = run(argv, capsys)
    assert status == 0, err
    report = json.loads(text)
    loaded = torch.jit.load("m.pt")
    assert report["order"] == loaded.filter.order == 21
    assert report["rho"] == loaded.filter.rho == 0.1
    assert report["notches"] == list(loaded.filter.notches)
    assert report["notches"] == sorted(report["notches"])  # ascending, whatever the argv order
    assert report["dims"] == list(loaded.filter.dims) == [-2, -1]
    assert report["adaptive"] is False and report["delay"] == 0.0  # odd order: compensated
    assert report["taps"] == loaded.filter.taps.numel() == 22 + 31 and report["compensated"]


# --- 5. help texts come from the values they describe -----------------------------------------


def help_text(command, capsys):
    assert main([command, "--help"]) == 0
    return " ".join(capsys.readouterr().out.split())  # argparse wraps lines


def test_defaults_are_the_library_defaults(capsys):
    parser = build_parser()
    demo = vars(parser.parse_args(["demo"]))
    sig = inspect.signature(run_demo).parameters
    for name in ("seed", "size", "order", "rho", "dpi"):
        assert demo[name] == sig[name].default
    text = help_text("demo", capsys)
    assert f"(default {sig['order'].default})" in text and f"(default {sig['rho'].default})" in text

    export = vars(parser.parse_args(["export", "--format", "onnx"]))
    assert (export["order"], export["rho"]) == (K.DEFAULT_ORDER, K.DEFAULT_RHO)
    opset = inspect.signature(X.export_onnx).parameters["opset"].default
    assert cli_export.DEFAULT_OPSET == opset
    text = help_text("export", capsys)
    assert f">= {X.MIN_OPSET}, default {opset}" in text and f"(default {K.DEFAULT_ORDER})" in text

    text = help_text("design", capsys)
    assert f"to {MAX_ORDER}" in text and f"{max_rho():.6g}" in text and "default 2pi/3, pi" in text


def test_format_frequency_round_trips():
    for w in (*K.DEFAULT_NOTCHES, 0.4 * np.pi, 1.234):
        text = cli_design.format_frequency(w)
        assert cli_design.parse_frequency(text) == pytest.approx(w, rel=1e-6)


# --- 7, 8. --version and python -m tof_fpn_torch ----------------------------------------------


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"tof-fpn {tof_fpn_torch.__version__}\n"


def test_python_dash_m():
    """``python -m tof_fpn_torch`` from the repository root runs this checkout's command line."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    for args, expect in ((["--help"], "usage: tof-fpn"), (["--version"], "tof-fpn ")):
        proc = subprocess.run(
            [sys.executable, "-m", "tof_fpn_torch", *args],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.startswith(expect)
    assert proc.stdout == f"tof-fpn {tof_fpn_torch.__version__}\n"


# --- 3. the README's command-line examples work as written ------------------------------------


def readme_commands() -> list[str]:
    """Every ``tof-fpn ...`` command in the README's "Command line" paragraph (up to the next
    heading): inline code spans and the lines of its code block, comments stripped."""
    text = (ROOT / "README.md").read_text()
    start = text.index("\nCommand line")
    block = text[start : text.index("\n## ", start)]
    commands = re.findall(r"(?<!`)`(tof-fpn [^`]*)`", block)
    for code in re.findall(r"```[a-z]*\n(.*?)```", block, flags=re.S):
        for line in code.splitlines():
            words = shlex.split(line, comments=True)
            if words and words[0] == "tof-fpn":
                commands.append(shlex.join(words))
    return commands


def test_readme_lists_every_command():
    commands = readme_commands()
    for name in ("design", "export", "demo", "clean", "calibrate", "convert", "--version"):
        assert any(c.split()[1] == name for c in commands), name
    assert any("--format onnx" in c for c in commands)
    assert not any(re.search(r"[|\[\]]", c) for c in commands)  # no a|b or [optional] notation


def _sample_frames(folder: str, walls: bool) -> None:
    """A few uint16-mm PNG pairs with a shared column pattern: flat slanted walls, or scenes
    (a step that moves, slopes that change: a camera moving through a room)."""
    from PIL import Image

    os.makedirs(folder)
    rng = np.random.default_rng(0)
    col = rng.normal(0.0, 1.5, 64)
    yy, xx = np.mgrid[0:48, 0:64]
    for i in range(4):
        d = 1500 + 100 * i + 2 * xx + yy + col[None, :] + rng.normal(0, 1, (48, 64))
        if not walls:
            d = d + 300 * ((xx > 20 + 8 * i) & (yy > 14 + 4 * i)) + 0.7 * i * xx
        Image.fromarray(np.rint(d).astype(np.uint16)).save(f"{folder}/f{i}_depth.png")
        Image.fromarray(np.full((48, 64), 200, np.uint16)).save(f"{folder}/f{i}_amplitude.png")


def test_readme_commands_work_as_written(cwd, capsys, monkeypatch):
    if importlib.util.find_spec("onnx") is not None:
        monkeypatch.setattr(X, "export_onnx", _fake_export_onnx())  # the real one: test_export.py
    # the convert example's input: the real Azure Kinect recording (fails, never skips, if absent)
    shutil.copyfile(real_capture("azure_kinect/desk_recording.mkv"), "desk_recording.mkv")
    _sample_frames("wall_frames", walls=True)  # the folders the README's examples name
    _sample_frames("my_frames", walls=False)
    for command in readme_commands():
        words = shlex.split(command)
        if "onnx" in words and importlib.util.find_spec("onnxscript") is None:
            continue
        status, out, err = run(words[1:], capsys)
        assert status == 0, (command, err)
        for path in re.findall(r"(?:written to : |response plot   : |picture: )(\S+)", out):
            assert os.path.isfile(path), (command, path)
        if words[1] == "export":
            assert os.path.isfile(json.loads(out)["out"])
    expected = [
        "taps.npy",
        "resp.png",
        cli_export.DEFAULT_STEM + cli_export.SUFFIXES["torchscript"],
        os.path.join(cli_demo.DEFAULT_OUT, "demo.png"),
        "wall.npz",
        os.path.join("out", "f0_depth.png"),
        "cam.npz",
        os.path.join("recordings", "desk_recording.npz"),
    ]
    for path in expected:
        assert os.path.isfile(path), path
