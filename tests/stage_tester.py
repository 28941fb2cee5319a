"""One tester for the stage contract (:mod:`tof_fpn_torch.runtime.stage`), as kornia's BaseTester:
every run-time stage passes :func:`check_stage` (``tests/test_stage_contract.py`` runs it on each).

What it checks, on a striped low-sensing scene with holes of every kind:

- ``run`` gives ``(frame, record)``; ``forward`` gives the same frame; the frame has the input's
  shape, dtype and device; the record has exactly the declared fields, per frame ``(B,)`` and per
  pixel ``(B, 1, H, W)``;
- the inputs are not modified;
- invalid pixels (NaN, +-inf, 0, negative depth; NaN, inf or negative amplitude) come out bit for
  bit;
- each frame of a batch comes out as it does alone (batch independence); for a stage whose batch
  is a sequence in time (``sequence = True``), each prefix of the frames as it does in the whole
  (causality);
- float64 in, float64 out;
- TorchScript (``scriptable``): the scripted stage's ``forward`` and ``run`` equal eager;
- on a CUDA device, where there is one, the same as on the CPU.
"""

from __future__ import annotations

import math

import torch

from tof_fpn_torch.runtime.stage import Stage

__all__ = ["check_stage", "scene"]

TOL = 1e-5


def scene(b: int = 3, h: int = 36, w: int = 44, seed: int = 0, dtype=torch.float32):
    """(B, 1, H, W) depth in metres (a slanted plane with a step, column stripes at pi and
    2 pi / 3, noise following 1 / A) and amplitude (20-300), with holes of every kind."""
    g = torch.Generator().manual_seed(seed)
    y = torch.linspace(0, 1, h).view(1, 1, h, 1)
    x = torch.arange(w, dtype=torch.float64).view(1, 1, 1, w)
    amp = 20 + 280 * torch.rand(b, 1, h, w, generator=g, dtype=torch.float64)
    stripes = 0.01 * torch.cos(math.pi * x) + 0.006 * torch.cos(2 * math.pi / 3 * x)
    depth = 1.5 + 0.3 * y + 0.4 * (x > w // 2) + stripes
    depth = depth + (2.0 / amp) * torch.randn(b, 1, h, w, generator=g, dtype=torch.float64)
    depth[:, :, 3, 4] = math.nan
    depth[:, :, 5, 6] = 0.0
    depth[:, :, 7, 8] = math.inf
    depth[:, :, 9, 10] = -1.0
    depth[:, :, 11, 12] = -math.inf
    amp[:, :, 13, 14] = math.nan
    amp[:, :, 15, 16] = -5.0
    amp[:, :, 17, 18] = math.inf
    return depth.to(dtype), amp.to(dtype)


def _invalid(depth: torch.Tensor, amp: torch.Tensor | None) -> torch.Tensor:
    bad = ~torch.isfinite(depth) | (depth <= 0)
    if amp is not None:
        bad |= ~torch.isfinite(amp) | (amp < 0)
    return bad


def _bits_equal(a: torch.Tensor, b: torch.Tensor) -> bool:
    return bool(((a == b) | (torch.isnan(a) & torch.isnan(b))).all())


def _close(a: torch.Tensor, b: torch.Tensor, what: str) -> None:
    torch.testing.assert_close(a, b, atol=TOL, rtol=0, equal_nan=True, msg=what)


def _check_record(stage: Stage, record: dict, depth: torch.Tensor) -> None:
    fields = {f.name: f for f in type(stage).record}
    assert set(record) == set(fields), f"record {sorted(record)} != declared {sorted(fields)}"
    b = depth.shape[0]
    for name, value in record.items():
        want = (b,) if fields[name].per == "frame" else (b, 1, *depth.shape[-2:])
        assert tuple(value.shape) == want, f"record {name!r}: {tuple(value.shape)} != {want}"


def check_stage(
    stage: Stage,
    amplitude: bool = True,
    scriptable: bool = True,
    float64: bool = True,
    scene_kwargs: dict | None = None,
) -> None:
    """Every check of the module docstring on ``stage`` (``amplitude``: give it one)."""
    assert isinstance(stage, Stage), f"{type(stage).__name__} is not a Stage"
    stage = stage.eval()
    depth, amp = scene(**(scene_kwargs or {}))
    a = amp if amplitude else None
    before_d, before_a = depth.clone(), amp.clone()
    with torch.no_grad():
        out, record = stage.run(depth, a)
        frame = stage(depth, a)
    assert torch.equal(depth.nan_to_num(), before_d.nan_to_num()) and torch.equal(
        amp.nan_to_num(), before_a.nan_to_num()
    ), "an input was modified"
    assert out.shape == depth.shape and out.dtype == depth.dtype and out.device == depth.device
    assert _bits_equal(frame, out), "forward and run()[0] differ"
    _check_record(stage, record, depth)
    bad = _invalid(depth, a)
    assert _bits_equal(out[bad], depth[bad]), "an invalid pixel changed"
    for i in range(depth.shape[0]):
        # independent frames: each alone as in the batch; a sequence: causal, each prefix alone
        part = slice(0, i + 1) if type(stage).sequence else slice(i, i + 1)
        with torch.no_grad():
            one, rec_one = stage.run(depth[part], None if a is None else a[part])
        _close(one, out[part], f"frames {part} alone differ from the batch")
        for name, value in rec_one.items():
            _close(value, record[name][part], f"record {name!r} of frames {part} alone")
    if float64:
        d64 = depth.double()
        with torch.no_grad():
            y64 = stage(d64, None if a is None else a.double())
        assert y64.dtype == torch.float64, f"float64 in, {y64.dtype} out"
    if scriptable:
        scripted = torch.jit.script(stage)
        with torch.no_grad():
            _close(scripted(depth, a), out, "TorchScript forward differs from eager")
            s_out, s_rec = scripted.run(depth, a)
        _close(s_out, out, "TorchScript run differs from eager")
        assert set(s_rec) == set(record)
        for name in record:
            _close(s_rec[name], record[name], f"TorchScript record {name!r}")
    if torch.cuda.is_available():
        with torch.no_grad():
            g_out, g_rec = stage.to("cuda").run(depth.cuda(), None if a is None else a.cuda())
        stage.to("cpu")
        _close(g_out.cpu(), out, "CUDA differs from CPU")
        for name in record:
            _close(g_rec[name].cpu(), record[name], f"CUDA record {name!r}")
