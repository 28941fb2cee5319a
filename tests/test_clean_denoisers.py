"""Every denoiser of the registry (tof_fpn_torch.denoise.names) works in ``tof-fpn clean``: by name
in the config and on the command line, on frames with NaN holes, and it lowers the error."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _clean_data import png_folder

from tof_fpn_torch import denoise
from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import DENOISERS, CleanConfig, build_pipeline
from tof_fpn_torch.cli import main


def _noisy_frame(seed: int = 0, h: int = 40, w: int = 48):
    """A tilted plane with a step, noise sigma = k / A, ~3 % NaN holes; the amplitude (50 to 180
    counts) changes at the step (another material), as a guide does in a real capture."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    truth = 1.5 + 0.004 * yy + 0.002 * xx + 0.2 * (xx >= w // 2)
    amp = 50.0 + 100.0 * (xx >= w // 2) + 30.0 * yy / h + 2.0 * torch.rand(h, w, generator=g)
    depth = truth + (1.0 / amp) * torch.randn(h, w, generator=g)
    holes = torch.rand(h, w, generator=g) < 0.03
    depth[holes] = float("nan")
    return depth[None, None].float(), amp[None, None].float(), truth[None, None].float(), holes


def test_clean_offers_every_registered_name():
    assert set(denoise.names()) <= set(DENOISERS)
    for name in denoise.names():
        assert DENOISERS[name] is denoise.module_class(name)


@pytest.mark.parametrize("name", denoise.names())
def test_each_denoiser_runs_in_the_pipeline_and_lowers_the_error(name):
    depth, amp, truth, holes = _noisy_frame()
    pipe = build_pipeline(CleanConfig(stage="paper", notch="off", denoise=name))
    assert (
        isinstance(pipe.stage("denoise"), denoise.module_class(name)) and pipe.stage("fpn") is None
    )
    out, _ = pipe(depth, amp)
    assert out.shape == depth.shape and out.dtype == depth.dtype
    assert torch.isnan(out[0, 0][holes]).all()  # invalid pixels stay invalid
    valid = ~holes
    assert torch.isfinite(out[0, 0][valid]).all()
    err_in = (depth[0, 0][valid] - truth[0, 0][valid]).square().mean()
    err_out = (out[0, 0][valid] - truth[0, 0][valid]).square().mean()
    assert err_out < 0.8 * err_in, (name, float(err_in), float(err_out))


def test_aliases_and_options_reach_the_denoiser():
    pipe = build_pipeline(
        CleanConfig(
            stage="paper", notch="off", denoise="Sliding_DCT", denoise_options={"block_size": 8}
        )
    )
    assert isinstance(pipe.stage("denoise"), denoise.SlidingDCT)
    with pytest.raises(ValueError, match="unknown option.*'bogus'"):
        build_pipeline(
            CleanConfig(stage="paper", notch="off", denoise="bm3d", denoise_options={"bogus": 1})
        )
    with pytest.raises(ValueError, match="denoise must be 'none' or one of"):
        build_pipeline(CleanConfig(stage="paper", notch="off", denoise="wiener"))


@pytest.mark.parametrize("name", ["bm3d", "joint-bilateral"])
def test_cli_clean_with_a_registry_denoiser(tmp_path, capsys, name):
    src = png_folder(tmp_path / "in", 2, sub_every=0)
    out = tmp_path / "out"
    assert main(["clean", str(src), str(out), "--denoise", name, "--quiet"]) == 0
    assert f'denoise = "{name}"' in (out / "clean.toml").read_text()
    for i in range(2):
        d_in = tio.read_png(src / f"f{i:03d}_depth.png", allow_empty=True)[0, 0].numpy()
        d_out = tio.read_png(out / f"f{i:03d}_depth.png", allow_empty=True)[0, 0].numpy()
        assert np.array_equal(np.isnan(d_in), np.isnan(d_out))
        assert not np.array_equal(d_in, d_out, equal_nan=True)
    capsys.readouterr()


def test_one_registry_for_clean_and_denoise():
    """``tof-fpn clean``'s registry is the denoise package's: a name registered through either is
    built by both, with the same check of its options."""
    from tof_fpn_torch.clean import register_denoiser

    assert DENOISERS is denoise.DENOISERS and register_denoiser is denoise.register

    class Scale(torch.nn.Module):
        def __init__(self, factor: float = 0.5):
            super().__init__()
            self.factor = factor

        def forward(self, depth, amplitude=None):
            return depth * self.factor

    register_denoiser("scale_it", Scale)
    try:
        assert "scale_it" in denoise.names() and denoise.get("scale_it", factor=3.0).factor == 3.0
        pipe = build_pipeline(
            CleanConfig(stage="paper", notch="off", denoise="scale_it", denoise_options={})
        )
        assert isinstance(pipe.stage("denoise").module, Scale) and not denoise.scriptable(
            "scale_it"
        )
        with pytest.raises(
            ValueError, match=r"has no parameter\(s\) \['size'\]; allowed: \['factor'\]"
        ):
            denoise.get("scale_it", size=2)
    finally:
        denoise.DENOISERS.pop("scale_it")
    assert "scale_it" not in DENOISERS
    with pytest.raises(ValueError, match="unknown denoiser 'scale_it'"):
        denoise.get("scale_it")
