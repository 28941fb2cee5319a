r"""A compact learned depth denoiser and the whole model: front end + network, invalid pixels kept.

:class:`DnCNN` is a small residual CNN (Zhang et al., IEEE TIP 2017, "Beyond a Gaussian denoiser"),
here with four input channels: the depth (metres, minus its per-image valid mean), what the front
end removed from it (metres; zero without a front end), the amplitude (``log1p``, minus its
per-image mean) and the validity mask; it predicts a depth correction.

:class:`DepthModel` is what is trained and exported: ``front_end(depth, amplitude)`` (any module
with that signature, e.g. :class:`~tof_fpn_torch.runtime.FPNSuppression`, or None), then the
network on the result with invalid pixels filled by the image's valid mean (a network must see
numbers), then the input put back at every invalid pixel: invalid stays invalid, bit for bit.
The network also sees ``depth - front_end(depth)``: a linear notch removes scene detail at the
FPN frequencies with the stripes, and without that channel the network could not put it back
(measured: the stage in front lost 0.7 dB against the network alone; ``docs/learn.md``).
TorchScript- and ONNX-exportable (the front end frozen first, see
:func:`tof_fpn_torch.runtime.freeze`).
"""

from __future__ import annotations

import torch
from torch import nn

from ..runtime._checks import check_image, check_same_shape
from ..runtime.validity import valid_mask

__all__ = ["DepthModel", "DnCNN"]


class DnCNN(nn.Module):
    """Residual CNN: ``depth + net([depth, removed, amplitude, valid])`` on (B, 1, H, W) inputs.

    Args:
        depth_layers: convolution layers (>= 2).
        channels: feature channels.
    """

    def __init__(self, depth_layers: int = 6, channels: int = 32) -> None:
        super().__init__()
        if isinstance(depth_layers, bool) or not isinstance(depth_layers, int) or depth_layers < 2:
            raise ValueError(f"depth_layers must be an int >= 2, got {depth_layers!r}")
        if isinstance(channels, bool) or not isinstance(channels, int) or channels < 1:
            raise ValueError(f"channels must be an int >= 1, got {channels!r}")
        layers: list[nn.Module] = [nn.Conv2d(4, channels, 3, padding=1), nn.ReLU()]
        for _ in range(depth_layers - 2):
            layers += [nn.Conv2d(channels, channels, 3, padding=1), nn.ReLU()]
        last = nn.Conv2d(channels, 1, 3, padding=1)
        nn.init.zeros_(last.weight)  # starts as the identity: training only has to improve on it
        nn.init.zeros_(last.bias)
        layers.append(last)
        self.net = nn.Sequential(*layers)

    def forward(
        self,
        depth: torch.Tensor,
        amplitude: torch.Tensor,
        valid: torch.Tensor,
        removed: torch.Tensor,
    ) -> torch.Tensor:
        v = valid.to(depth.dtype)
        count = v.sum((-2, -1), keepdim=True).clamp_min(1.0)
        mean_d = (depth * v).sum((-2, -1), keepdim=True) / count
        la = torch.log1p(amplitude.clamp_min(0.0))
        mean_a = (la * v).sum((-2, -1), keepdim=True) / count
        x = torch.cat([(depth - mean_d) * v, removed * v, (la - mean_a) * v, v], 1)
        return depth + self.net(x)


class DepthModel(nn.Module):
    """Front end, then the network; invalid pixels come out as they went in.

    Args:
        network: a module ``(depth, amplitude, valid, removed) -> depth`` (e.g. :class:`DnCNN`).
        front_end: a module ``(depth, amplitude) -> depth`` or None.

    Shape:
        depth, amplitude: (B, 1, H, W) float; output (B, 1, H, W).
    """

    def __init__(self, network: nn.Module, front_end: nn.Module | None = None) -> None:
        super().__init__()
        self.front_end = front_end
        self.network = network

    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        check_image(depth, "depth", 1)
        check_image(amplitude, "amplitude", 1)
        check_same_shape(amplitude, depth, "amplitude", "depth")
        valid = valid_mask(depth, amplitude)
        x = depth
        front = self.front_end
        if front is not None:
            x = front(depth, amplitude)
        v = valid.to(x.dtype)
        mean = (torch.where(valid, x, torch.zeros_like(x)) * v).sum((-2, -1), keepdim=True)
        mean = mean / v.sum((-2, -1), keepdim=True).clamp_min(1.0)
        filled = torch.where(valid, x, mean.expand_as(x))
        amp = torch.where(valid, amplitude, torch.zeros_like(amplitude))
        # what the front end took away, so that the network can put back what it should not have
        removed = torch.where(valid, depth - x, torch.zeros_like(x))
        out = self.network(filled, amp, valid, removed)
        return torch.where(valid, out, depth)
