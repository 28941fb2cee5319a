"""The README's Python example runs as written and does what its comments say."""

from __future__ import annotations

import math
import re
from pathlib import Path

import torch

README = Path(__file__).resolve().parents[1] / "README.md"


def test_api_example_runs_and_keeps_a_stripe_free_frame():
    text = README.read_text()
    block = re.search(r"<!-- api-example -->\s*```python\n(.*?)```", text, re.S)
    assert block, "README has no <!-- api-example --> python block"
    scope: dict = {}
    exec(compile(block.group(1), str(README), "exec"), scope)  # noqa: S102 - our own README
    d, depth, clean = scope["d"], scope["depth"], scope["clean"]
    assert abs(d.dc_gain - 1.0) < 1e-12 and round(d.ripple_db, 1) == -29.5
    assert torch.equal(clean, depth)  # the comment's claim: no stripes, unchanged
    striped = depth + 0.02 * torch.cos(math.pi * torch.arange(depth.shape[-1]))
    out = scope["stage"](striped, scope["amplitude"])
    assert (out - depth).abs().mean() < 0.2 * (striped - depth).abs().mean()
