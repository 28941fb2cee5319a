"""A module with trainable notch taps (a KeepZeros parametrisation) is refused by torch.jit.script
with a message naming tof_fpn_torch.runtime.freeze (TorchScript cannot run parametrisations: the
scripted module used to fail on its first call); frozen, it scripts and matches eager."""

from __future__ import annotations

import copy

import pytest
import torch
from torch.nn.utils import parametrize

from tof_fpn_torch.build import trainable_suppression
from tof_fpn_torch.learn.models import DepthModel, DnCNN
from tof_fpn_torch.runtime import freeze


def _frames():
    g = torch.Generator().manual_seed(0)
    x = torch.arange(48.0)
    depth = 2.0 + 0.01 * torch.randn(2, 1, 32, 48, generator=g) + 0.02 * torch.cos(torch.pi * x)
    amp = 50.0 + 200.0 * torch.rand(2, 1, 32, 48, generator=g)
    return depth, amp


@pytest.mark.parametrize("whole_model", [False, True])
def test_scripting_a_trainable_module_is_refused_then_works_frozen(whole_model):
    stage = trainable_suppression()
    module = DepthModel(DnCNN(3, 4), stage) if whole_model else stage
    with pytest.raises(RuntimeError, match=r"Call tof_fpn_torch\.runtime\.freeze\(module\) first"):
        torch.jit.script(module)
    # the refusal leaves the module as it was: still trainable through G
    assert parametrize.is_parametrized(stage.filter, "taps")
    depth, amp = _frames()
    with torch.no_grad():
        ref = module(depth, amp)
    frozen = freeze(copy.deepcopy(module)).eval()
    scripted = torch.jit.script(frozen)
    torch.testing.assert_close(scripted(depth, amp), ref, rtol=0, atol=1e-6, equal_nan=True)
