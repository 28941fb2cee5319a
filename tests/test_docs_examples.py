"""The documentation's commands and Python examples run as written.

Every page under ``docs/`` (except ``NOT_RUN``) is run like a reader following it: its
```` ```bash ```` and ```` ```python ```` blocks, in page order, in a fresh temporary folder:

* a ``tof-fpn ...`` line is run in this process (``tof_fpn_torch.cli.main``, so torch is
  imported once) and must exit with 0; any other bash line is run by ``bash`` and must exit with
  0; a line ending in ``\\`` continues on the next;
* the Python blocks of a page share one namespace and run in the page's folder;
* a block right after ``<!-- docs-test: skip (REASON) -->`` is not run (installing packages,
  runs of minutes, a Ray cluster); after ``<!-- docs-test: file NAME -->`` the block is written
  to ``NAME`` (a configuration file a later command reads).

A page may name sample inputs it does not make itself; ``<!-- docs-test: samples NAME ... -->``
at its top lists them, and they are made in its folder first (``SAMPLES``):

* ``my_frames``: four PNG pairs of simulated frames, made by the same code as the Python block
  of ``docs/getting-started.md`` (the package's simulator and writers);
* ``wall_frames``: eight frames of flat walls at 1.5 m and 2.5 m from the same simulated camera
  (read-out FPN included), for ``tof-fpn calibrate``;
* ``desk_recording.mkv``, ``adi``: copies of the real Azure Kinect recording and of the ADI
  ADTF3175 wall files of ``tests/data/real`` (missing captures fail, as in ``conftest.py``).

The benchmark commands (``docs/benchmarks.md`` and every ``python benchmarks/...`` or
``python examples/...`` line) take minutes to hours and are not run here; their scripts must
exist. The pages must also hold no issue numbers and no run diaries (``test_no_issue_numbers``).
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from conftest import real_capture

from tof_fpn_torch.clean import steps as clean_steps

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

#: pages whose blocks are not run: the lead's architecture page (no commands) and the benchmarks
#: (hours of runs; their scripts are checked by test_benchmark_scripts_exist)
NOT_RUN = {"architecture.md", "benchmarks.md"}
#: pages run only with the slow tests (whole diagnoses, folders cleaned): ``-m slow``
SLOW = {"diagnosis.md", "clean.md"}

#: (command, seconds) of every command run, for the slowest-commands report
TIMES: list[tuple[str, float]] = []

_FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```\s*$", re.M | re.S)
_MARK = re.compile(r"<!--\s*docs-test:\s*(\w+)\s*(.*?)\s*-->")


def pages() -> list[Path]:
    return sorted(p for p in DOCS.rglob("*.md") if "_tooling" not in p.parts)


def guide_pages() -> list[str]:
    return [p.relative_to(DOCS).as_posix() for p in pages() if p.name not in NOT_RUN]


def blocks(text: str) -> list[tuple[str, str, tuple[str, str] | None]]:
    """``(language, code, marker)`` of every fenced block; the marker is the ``docs-test``
    comment on the line right before the fence, if any."""
    found = []
    for m in _FENCE.finditer(text):
        before = text[: m.start()].rstrip("\n").rsplit("\n", 1)[-1]
        mark = _MARK.fullmatch(before.strip())
        found.append((m.group(1), m.group(2), (mark.group(1), mark.group(2)) if mark else None))
    return found


def commands(code: str) -> list[str]:
    """The lines of a bash block, continuations joined, blank and comment lines dropped."""
    out, pending = [], ""
    for line in code.splitlines():
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        line, pending = pending + line, ""
        if line.strip() and not line.lstrip().startswith("#"):
            out.append(line.strip())
    return out


# --- sample inputs ------------------------------------------------------------------------------


def _my_frames(folder: Path) -> None:
    from tof_fpn_torch import io as tio
    from tof_fpn_torch.sim import Camera, Simulation, planar_scene

    os.makedirs(folder / "my_frames", exist_ok=True)
    sim = Simulation(Camera(integration_time=100e-6))
    for i in range(4):
        out = sim.run(planar_scene(120, 160, seed=i), frames=1, seed=i)
        tio.write_pair(
            folder / f"my_frames/take{i}_depth.png",
            out.depth,
            out.amplitude,
            folder / f"my_frames/take{i}_amplitude.png",
        )


def _wall_frames(folder: Path) -> None:
    from tof_fpn_torch import io as tio
    from tof_fpn_torch.sim import Camera, Scene, Simulation

    os.makedirs(folder / "wall_frames", exist_ok=True)
    sim = Simulation(Camera(integration_time=100e-6))
    for d, distance in enumerate((1.5, 2.5)):
        wall = Scene(torch.full((1, 1, 120, 160), distance), torch.full((1, 1, 120, 160), 0.6))
        out = sim.run(wall, frames=4, seed=d)
        for f in range(4):
            tio.write_pair(
                folder / f"wall_frames/wall{d}_{f}_depth.png",
                out.depth[f : f + 1],
                out.amplitude[f : f + 1],
                folder / f"wall_frames/wall{d}_{f}_amplitude.png",
            )


def _mkv(folder: Path) -> None:
    shutil.copyfile(real_capture("azure_kinect/desk_recording.mkv"), folder / "desk_recording.mkv")


def _adi(folder: Path) -> None:
    os.makedirs(folder / "adi", exist_ok=True)
    for name in ("wall_depth_u16le_512x512.bin", "wall_ir_u16le_512x512.bin"):
        shutil.copyfile(real_capture(f"adi_adtf3175/{name}"), folder / "adi" / name)


SAMPLES = {
    "my_frames": _my_frames,
    "wall_frames": _wall_frames,
    "desk_recording.mkv": _mkv,
    "adi": _adi,
}


# --- running a page -----------------------------------------------------------------------------


def _run_command(line: str, capsys) -> None:
    words = shlex.split(line, comments=True)
    if not words:
        return
    start = time.perf_counter()
    try:
        _run_words(line, words, capsys)
    finally:
        TIMES.append((line, time.perf_counter() - start))


def _run_words(line: str, words: list[str], capsys) -> None:
    if words[0] == "tof-fpn":
        from tof_fpn_torch.cli import main

        status = main(words[1:])
        out = capsys.readouterr()
        assert status == 0, f"{line!r} exited with {status}:\n{out.err}{out.out}"
        return
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    proc = subprocess.run(["bash", "-ec", line], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, f"{line!r} exited with {proc.returncode}:\n{proc.stderr}"


@pytest.mark.parametrize(
    "page",
    [pytest.param(p, marks=pytest.mark.slow) if p in SLOW else p for p in guide_pages()],
)
def test_page_runs_as_written(page, tmp_path, monkeypatch, capsys):
    text = (DOCS / page).read_text()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    for name, arg in _MARK.findall(text):
        if name == "samples":
            for sample in arg.split():
                SAMPLES[sample](tmp_path)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # on a shared machine more threads wait for each other (docs/clean.md)
    namespace: dict = {"__name__": "__docs__"}
    registered = [s.name for s in clean_steps.steps()]
    try:
        for lang, code, mark in blocks(text):
            if mark and mark[0] == "file":
                Path(mark[1]).write_text(code)
                continue
            if lang not in ("bash", "python"):
                continue
            if mark and mark[0] == "skip":
                assert mark[1].strip("() "), f"{page}: a skipped block must say why"
                continue
            if lang == "python":
                exec(compile(code, f"{page} (python block)", "exec"), namespace)  # noqa: S102
            else:
                for line in commands(code):
                    _run_command(line, capsys)
    finally:
        torch.set_num_threads(threads)
        for step in clean_steps.steps():  # a page that registers a step (adding-a-stage.md)
            if step.name not in registered:
                clean_steps.unregister(step.name)


def test_blocks_are_parsed():
    """The extraction itself: markers bind to the next fence only, continuations join."""
    text = (
        "<!-- docs-test: skip (slow) -->\n```bash\na\n```\n\n```bash\nb \\\n  c\n# no\n```\n"
        "<!-- docs-test: file x.toml -->\n```toml\nk = 1\n```\n"
    )
    found = blocks(text)
    assert [(lang, mark) for lang, _, mark in found] == [
        ("bash", ("skip", "(slow)")),
        ("bash", None),
        ("toml", ("file", "x.toml")),
    ]
    assert [c.split() for c in commands(found[1][1])] == [["b", "c"]]


# --- what is not run ----------------------------------------------------------------------------


def test_benchmark_scripts_exist():
    named = set()
    for page in pages():
        named |= set(re.findall(r"python ((?:benchmarks|examples)/[\w/]+\.py)", page.read_text()))
    assert named, "the docs name no benchmark script"
    missing = []
    for rel in sorted(named):
        if not (ROOT / rel).is_file():
            missing.append(rel)
    assert not missing, f"docs name scripts that do not exist: {missing}"


def test_no_issue_numbers_or_diaries():
    bad = re.compile(r"Issue \d|issue \d+\b|reported blocked|\b20\d\d-\d\d-\d\d\b")
    found = []
    for path in [*pages(), ROOT / "README.md"]:
        if "figures" in path.parts:
            continue  # raw result files written by the benchmark scripts
        for i, line in enumerate(path.read_text().splitlines(), 1):
            if bad.search(line):
                found.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not found, "\n".join(found)
