"""The table of file formats (``tof_fpn_torch.io.formats``): every suffix belongs to one format,
every format with a writer round-trips, the reader of a format whose optional extra is missing
says what to install, ``tof_fpn_torch/io`` has no import circle, docs/io.md shows the table."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import numpy as np
import pytest
from test_io_formats import PAIRS  # the round trips of every format with a writer

from tof_fpn_torch import io as tio
from tof_fpn_torch.cli import main
from tof_fpn_torch.io import _table
from tof_fpn_torch.io import formats as F
from tof_fpn_torch.io.stored import read_frame_sets

ROOT = Path(__file__).resolve().parents[1]
IO = ROOT / "tof_fpn_torch" / "io"


def test_every_suffix_maps_to_exactly_one_format():
    owners: dict[str, list[str]] = {}
    for fmt in F.formats():
        for s in fmt.suffixes:
            owners.setdefault(s, []).append(fmt.name)
    assert {s: n for s, n in owners.items() if len(n) != 1} == {}
    assert len(owners) >= 12  # .npz .h5 .hdf5 .npy .png .tif .tiff .bin .raw .mkv .bag .mcap .db3
    for s, (name,) in owners.items():
        for file_name in (f"take{s}", f"take{s.upper()}", f"dir.d/take_depth{s}"):
            assert F.format_of_name(file_name, by_name=False).name == name, file_name
            assert F.format_for(file_name).name == name, file_name
    assert F.format_of_name("take.jpg") is None and F.format_of_name("README") is None


def test_camera_files_are_found_by_name_before_their_suffix():
    for name, fmt in (
        ("wall_depth_u16le_512x512.bin", "adi_depth_ir"),
        ("wall_IR_u16le_4x6.RAW", "adi_depth_ir"),
        ("office_interleaved_512x512.bin", "adi_interleaved"),
        ("wall_depth.bin", "raw"),
        ("x_interleaved_4x4.png", "png"),
    ):
        assert F.format_of_name(name).name == fmt, name
    # the frame-file tools go by suffix: an ADI name is a raw file there
    assert F.format_of_name("wall_depth_u16le_512x512.bin", by_name=False).name == "raw"


def test_a_ros2_bag_folder_is_a_file_of_its_format(tmp_path):
    bag, plain = tmp_path / "take", tmp_path / "plain"
    bag.mkdir()
    plain.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 5\n")
    (plain / "metadata.yaml").write_text("something: else\n")
    assert F.format_for(bag).name == "ros2_bag"
    assert F.format_for(plain) is None


def test_a_taken_suffix_or_name_is_refused_and_a_new_format_is_found(monkeypatch):
    monkeypatch.setattr(_table, "_FORMATS", dict(_table._FORMATS))  # the test's own table
    monkeypatch.setattr(_table, "_BY_SUFFIX", dict(_table._BY_SUFFIX))
    with pytest.raises(ValueError, match=r"taken: \{'\.npy': 'npy'\}"):
        F.register(F.FileFormat("mine", F.PAIR_MEMBER, "my arrays", (".npy",)))
    with pytest.raises(ValueError, match="'png' is registered already"):
        F.register(F.FileFormat("png", F.PAIR_MEMBER, "PNG again", (".pgm",)))
    with pytest.raises(ValueError, match="lower-case"):
        F.FileFormat("upper", F.PAIR_MEMBER, "upper", (".PGM",))
    mine = F.register(F.FileFormat("pgm", F.PAIR_MEMBER, "portable grey map", (".pgm",)))
    assert F.format_for("a.pgm") is mine and ".pgm" in F.suffixes(F.PAIR_MEMBER)
    with pytest.raises(ValueError, match="portable grey map .* no reader"):
        mine.read("a.pgm", "depth")


def test_every_format_with_a_writer_has_a_round_trip_test():
    """``tests/test_io_formats.py`` writes and reads back every format of ``PAIRS`` exactly
    (``write_pair`` / ``read_pair``, which call the table's writer and reader)."""
    tested = {
        F.format_of_name(n, by_name=False).name for names in PAIRS.values() for n in names if n
    }
    with_writer = {f.name for f in F.formats() if f.writer is not None}
    assert with_writer == tested
    assert {f.name for f in F.formats(F.PAIR_MEMBER, F.FRAME_SET)} <= with_writer


@pytest.mark.parametrize(
    ("module", "suffix", "extra"),
    [("av", ".mkv", "mkv"), ("rosbags", ".bag", "bag"), ("rosbags", ".db3", "bag")],
)
def test_a_missing_extra_is_named_by_the_table_reader(tmp_path, monkeypatch, module, suffix, extra):
    path = tmp_path / f"take{suffix}"
    path.write_bytes(b"any bytes: the reader stops before reading them")
    monkeypatch.setitem(sys.modules, module, None)  # import <module> -> ImportError
    hint = f'pip install "tof_fpn_torch[{extra}]"'
    fmt = F.format_for(path)
    for call in (
        lambda: fmt.read(path),
        lambda: tio.read_any_recording(path),
        lambda: read_frame_sets(path),
    ):
        with pytest.raises(tio.MissingExtraError) as info:
            call()
        assert str(info.value).endswith(hint) and f"'{module}' is not installed" in str(info.value)
        assert isinstance(info.value, ImportError) and info.value.__cause__ is None
        assert info.value.__suppress_context__  # one message, not an ImportError traceback


def test_convert_without_pyav_names_the_extra(tmp_path, monkeypatch, capsys):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "take.mkv").write_bytes(b"not read")
    monkeypatch.setitem(sys.modules, "av", None)
    status = main(["convert", str(tmp_path / "in"), str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1 and len(err) == 1 and err[0].startswith("tof-fpn convert: error: take.mkv")
    assert err[0].endswith('pip install "tof_fpn_torch[mkv]"')


def test_the_camera_formats_read_through_the_table(tmp_path):
    d = np.arange(1, 25, dtype="<u2").reshape(1, 4, 6)
    d.tofile(tmp_path / "w_depth_u16le_4x6.bin")
    (d + 100).tofile(tmp_path / "w_ir_u16le_4x6.bin")
    fmt = F.format_for(tmp_path / "w_depth_u16le_4x6.bin")
    (fs,) = fmt.read_stored(tmp_path / "w_depth_u16le_4x6.bin", tmp_path / "w_ir_u16le_4x6.bin")
    assert fs.camera == "adtf3175" and fs.depth.dtype == np.uint16
    np.testing.assert_array_equal(fs.amplitude, d + 100)


def _io_imports() -> dict[str, set[str]]:
    """Module -> the modules of tof_fpn_torch/io it imports (function-level imports too)."""
    modules = {p.stem for p in IO.glob("*.py")}
    graph = {}
    for p in IO.glob("*.py"):
        deps = set()
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                deps |= {node.module.split(".")[0]} if node.module else {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                "tof_fpn_torch.io."
            ):
                deps.add(node.module.split(".")[2])
            elif isinstance(node, ast.Import):
                deps |= {
                    a.name.split(".")[2]
                    for a in node.names
                    if a.name.startswith("tof_fpn_torch.io.")
                }
        graph[p.stem] = (deps & modules) - {p.stem}
    return graph


def _reach(graph: dict[str, set[str]], start: str) -> set[str]:
    seen, todo = set(), list(graph[start])
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo += graph[m]
    return seen


def test_no_import_circle_in_io():
    graph = _io_imports()
    assert "formats" in graph["stored"] and "formats" in graph["pairs"]  # the graph is read
    circles = sorted(m for m in graph if m in _reach(graph, m))
    assert circles == []
    # the table imports only the formats' modules, none of which imports it back
    assert "formats" not in set().union(*(_reach(graph, m) for m in graph["formats"]))


def test_the_docs_show_the_table_of_the_code():
    page = (ROOT / "docs" / "io.md").read_text()
    start = "<!-- generated by tof_fpn_torch.io.formats.markdown_table()"
    assert start in page, "docs/io.md lost the table of formats"
    shown = page.split(start, 1)[1].split("-->\n", 1)[1].split("<!-- end of")[0]
    assert shown == F.markdown_table(), (
        "docs/io.md's table of formats differs from the code: paste "
        "tof_fpn_torch.io.formats.markdown_table() between the markers"
    )


def test_one_decoder_per_format_the_tensor_and_stored_readers_agree(tmp_path):
    """``read_pair`` (tensors) and ``read_frame_sets`` (as stored) decode a file the same way:
    the same values, and the same files refused."""
    from PIL import Image

    from tof_fpn_torch.io.stored import frame_set_tensors

    rng = np.random.default_rng(5)
    mm = rng.integers(0, 4000, (2, 3, 4)).astype(np.uint16)
    counts = rng.integers(0, 4000, (2, 3, 4)).astype(np.uint16)
    np.save(tmp_path / "a_depth.npy", mm)
    np.save(tmp_path / "a_amplitude.npy", counts)
    np.savez(tmp_path / "b.npz", depth=mm, amplitude=counts)
    tio.write_hdf5(tmp_path / "c.h5", tio.read_npy(tmp_path / "a_depth.npy", allow_empty=True),
                   tio.read_npy(tmp_path / "a_amplitude.npy", "amplitude"), depth_scale=0.002)  # fmt: skip
    Image.fromarray(mm[0]).save(tmp_path / "d_depth.png")
    Image.fromarray(counts[0]).save(tmp_path / "d_amplitude.png")
    for depth_path in ("a_depth.npy", "b.npz", "c.h5", "d_depth.png"):
        amp = depth_path.replace("_depth", "_amplitude") if "_depth" in depth_path else None
        args = (tmp_path / depth_path, None if amp is None else tmp_path / amp)
        d, a = tio.read_pair(*args, allow_empty=True)
        (fs,) = read_frame_sets(*args)
        d2, a2 = frame_set_tensors(fs, allow_empty=True)
        assert np.array_equal(d.numpy(), d2.numpy(), equal_nan=True), depth_path
        assert np.array_equal(a.numpy(), a2.numpy()), depth_path
    assert fs.depth.dtype == np.uint16 and np.nanmax(d.numpy()) == np.float32(mm[0].max() * 1e-3)
    # a palette image is colour, a JPEG named .png is not a PNG: refused on both sides
    Image.fromarray(mm[0].astype(np.uint8)).convert("P").save(tmp_path / "p_depth.png")
    Image.fromarray(mm[0].astype(np.uint8)).save(tmp_path / "j_depth.png", format="JPEG")
    for bad, needle in (("p_depth.png", "single-channel integer"), ("j_depth.png", "not a PNG")):
        amp = tmp_path / "d_amplitude.png"
        with pytest.raises(tio.FormatError, match=needle):
            tio.read_png(tmp_path / bad, depth_scale=1e-3)
        with pytest.raises(tio.FormatError, match=needle):
            read_frame_sets(tmp_path / bad, amp, depth_scale=1e-3)
