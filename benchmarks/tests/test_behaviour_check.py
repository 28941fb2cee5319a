"""The behaviour check's compare logic and normaliser (benchmarks/behaviour_check.py), on
hand-made records; the fixed set of runs itself is not run here."""

from __future__ import annotations

import copy
import io
import json
import zipfile

import behaviour_check as bc


def _record() -> dict:
    return {
        "format": 1,
        "commands": {
            "demo": {
                "argv": ["tof-fpn", "demo", "--out", "demo"],
                "returncode": 0,
                "stdout": ["created directory demo", "  picture: demo/demo.png  (<time>)"],
            }
        },
        "inputs": {"inputs/a.png": {"compare": "sha256", "sha256": "11" * 32}},
        "outputs": {
            "demo/demo.png": {"compare": "sha256", "sha256": "aa" * 32},
            "demo/demo.json": {
                "compare": "normalised_sha256",
                "sha256": "cc" * 32,
                "normalised_sha256": "bb" * 32,
                "content": {"psnr": 21.2},
            },
        },
        "meta": {"wall_s": 100.0, "versions": {"torch": "2.0"}},
    }


def _main(tmp_path, a: dict, b: dict, capsys) -> tuple[int, str]:
    pa, pb = tmp_path / "a.json", tmp_path / "b.json"
    pa.write_text(json.dumps(a))
    pb.write_text(json.dumps(b))
    status = bc.main(["compare", str(pa), str(pb)])
    return status, capsys.readouterr().out


def test_identical_records_compare_equal_and_exit_0(tmp_path, capsys):
    a = _record()
    b = copy.deepcopy(a)
    b["meta"] = {"wall_s": 250.0, "versions": {"torch": "2.0"}}  # meta is never a difference
    b["outputs"]["demo/demo.json"]["sha256"] = "dd" * 32  # raw bytes of a normalised file: ignored
    assert bc.compare(a, b) == []
    status, out = _main(tmp_path, a, b, capsys)
    assert status == 0
    assert "identical" in out


def test_one_hash_differs_exits_1_and_names_the_file(tmp_path, capsys):
    a = _record()
    b = copy.deepcopy(a)
    b["outputs"]["demo/demo.png"]["sha256"] = "ab" * 32
    diffs = bc.compare(a, b)
    assert len(diffs) == 1
    assert "demo/demo.png" in diffs[0]
    status, out = _main(tmp_path, a, b, capsys)
    assert status == 1
    assert "demo/demo.png" in out
    assert "demo/demo.json" not in out


def test_missing_extra_stdout_and_normalised_content_differences_are_listed():
    a = _record()
    b = copy.deepcopy(a)
    del b["outputs"]["demo/demo.png"]
    b["outputs"]["demo/new.png"] = {"compare": "sha256", "sha256": "ee" * 32}
    b["commands"]["demo"]["stdout"][0] = "created folder demo"
    b["outputs"]["demo/demo.json"]["normalised_sha256"] = "ff" * 32
    b["outputs"]["demo/demo.json"]["content"] = {"psnr": 21.3}
    text = "\n".join(bc.compare(a, b))
    assert "demo/demo.png: missing in B" in text
    assert "demo/new.png: extra in B" in text
    assert "stdout line 1 differs" in text
    assert "created folder demo" in text
    assert "demo/demo.json: normalised content hash differs" in text
    assert "psnr: 21.2 -> 21.3" in text


def test_model_outputs_differ_even_when_the_archive_is_the_same():
    a = _record()
    a["outputs"]["export/m.pt"] = {
        "compare": "sha256",
        "sha256": "12" * 32,
        "model": {"outputs": [{"shape": [2, 1, 4, 4], "sha256": "34" * 32}]},
    }
    b = copy.deepcopy(a)
    b["outputs"]["export/m.pt"]["model"]["outputs"][0]["sha256"] = "56" * 32
    diffs = bc.compare(a, b)
    assert diffs[0] == "output export/m.pt: model outputs on the fixed input differ"


def test_normaliser_drops_timing_keys_and_keeps_values():
    record = {
        "time": "2026-11-28T10:56:21.318Z",
        "compute_s": 0.048,
        "seconds": 0.45,
        "run": "2761-55bb8415",
        "version": "0.2.0",
        "input": {"mtime_ns": [1795863378855578179], "size": [73164]},
        "integration_time": 0.0003,  # a camera setting, not a time of the run
        "timestamps_s": [0.0, 0.033],  # the frames' times: data
        "report": {"changed": 0.19, "noise_mm": 0.278},
        "source": "/tmp/x/out/wall.png",
    }
    out, dropped = bc.normalise(record, {"/tmp/x/out": "<OUT>"})
    assert out == {
        "input": {"size": [73164]},
        "integration_time": 0.0003,
        "timestamps_s": [0.0, 0.033],
        "report": {"changed": 0.19, "noise_mm": 0.278},
        "source": "<OUT>/wall.png",
    }
    assert sorted(dropped) == ["compute_s", "input.mtime_ns", "run", "seconds", "time", "version"]


def test_normaliser_of_a_manifest_line_list_and_the_stdout_mask():
    lines = [{"event": "start", "time": "x", "todo": 1}, {"status": "done", "read_s": 0.1}]
    out, dropped = bc.normalise(lines)
    assert out == [{"event": "start", "todo": 1}, {"status": "done"}]
    assert dropped == ["[].read_s", "[].time"]
    masked = bc.mask_text(
        "cleaned 1 file(s) (1 frames) in 0.5 s, 2.2 frames/s; output /tmp/x/out/a\n"
        "column stripe energy down 16.3 dB\n"
        "files 1/2\rfiles 2/2\n"
    )
    assert masked == [
        "cleaned 1 file(s) (1 frames) in <time>, <rate>; output <path>",
        "column stripe energy down 16.3 dB",
        "files 2/2",
    ]


def test_normaliser_rounds_floats_to_twelve_digits():
    # two runs of one command measured these (the last binary digit differs); a real change is
    # several orders of magnitude larger and stays a difference
    a, _ = bc.normalise({"stripe_scale": 0.43020203972799115})
    b, _ = bc.normalise({"stripe_scale": 0.4302020397279912})
    c, _ = bc.normalise({"stripe_scale": 0.43020203973})
    assert a == b == {"stripe_scale": 0.430202039728}
    assert c != a
    assert bc.normalise({"x": float("nan"), "n": 3})[0] == {"x": "nan", "n": 3}


def _archive(code: bytes, debug: bytes, serial: bytes) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("m/code/__torch__/stage.py", code)
        zf.writestr("m/code/__torch__/stage.py.debug_pkl", debug)
        zf.writestr("m/.data/serialization_id", serial)
    return buf.getvalue()


def test_torchscript_archive_hash_leaves_out_debug_information_only():
    base = bc.torchscript_members(_archive(b"def f(x): return x", b"/work/a/stage.py:10", b"1"))
    moved = bc.torchscript_members(_archive(b"def f(x): return x", b"/work/b/stage.py:12", b"2"))
    edited = bc.torchscript_members(_archive(b"def f(x): return -x", b"/work/a/stage.py:10", b"1"))
    assert list(base) == ["code/__torch__/stage.py"]
    assert moved == base
    assert edited != base


def _onnx_model(mid: str, op: str, trace: str) -> bytes:
    from onnx import TensorProto, helper

    n1 = helper.make_node("Add", ["x", "one"], [mid], name=f"node_add_{len(mid)}")
    n1.metadata_props.add(key="pkg.torch.onnx.stack_trace", value=trace)
    n2 = helper.make_node(op, [mid, mid], ["y"], name="node_out")
    one = helper.make_tensor("one", TensorProto.FLOAT, [1], [1.0])
    graph = helper.make_graph(
        [n1, n2],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [2])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [2])],
        [one],
    )
    return helper.make_model(graph).SerializeToString()


def test_onnx_hash_ignores_debug_information_and_value_numbering_only():
    base = bc.onnx_normalised(_onnx_model("val_7", "Mul", 'File "/work/a/stage.py", line 10'))
    renumbered = bc.onnx_normalised(_onnx_model("val_12", "Mul", 'File "/work/b/x.py", line 3'))
    other_op = bc.onnx_normalised(_onnx_model("val_7", "Add", 'File "/work/a/stage.py", line 10'))
    assert renumbered == base
    assert other_op["normalised_sha256"] != base["normalised_sha256"]
    assert other_op["ops"] == {"Add": 2}
