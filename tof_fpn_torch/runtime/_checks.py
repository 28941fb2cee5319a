"""Shared argument checks for the run-time modules (TorchScript-clean, torch only).

Every check raises :class:`ValueError` naming what was given and what is allowed.
"""

from __future__ import annotations

import torch

__all__ = [
    "check_tensor_type",
    "check_fusion_inputs",
    "check_image",
    "check_same_shape",
    "check_taps",
    "normalize_dims",
]


@torch.jit.unused
def check_tensor_type(x, name: str, optional: bool = False) -> None:
    """``TypeError`` unless ``x`` is a ``torch.Tensor`` (or None where ``optional``), with the
    conversion a NumPy array needs (eager only: TorchScript types its arguments itself)."""
    if isinstance(x, torch.Tensor) or (optional and x is None):
        return
    kind = type(x).__module__ + "." + type(x).__name__
    hint = " (a NumPy array: torch.from_numpy(x))" if kind.startswith("numpy.") else ""
    raise TypeError(
        f"{name} must be a torch.Tensor of shape (B, C, H, W){' or None' if optional else ''}, "
        f"got {kind}{hint}"
    )


def check_image(x: torch.Tensor, name: str, channels: int | None = None) -> None:
    """Check that ``x`` is a floating (B, C, H, W) tensor (with ``C == channels`` if given)."""
    if not torch.jit.is_scripting():
        check_tensor_type(x, name)
    if x.dim() != 4:
        raise ValueError(
            f"{name} must have shape (B, C, H, W) (4 dimensions), got {x.dim()} dimensions "
            f"with shape {list(x.shape)}"
        )
    if not x.is_floating_point():
        raise ValueError(
            f"{name} must be a floating-point tensor (float16/bfloat16/float32/float64), "
            f"got dtype {x.dtype}; convert it with .float() first"
        )
    if channels is not None and x.shape[1] != channels:
        raise ValueError(
            f"{name} must have {channels} channel(s), shape (B, {channels}, H, W), "
            f"got shape {list(x.shape)}"
        )


def check_same_shape(a: torch.Tensor, b: torch.Tensor, name_a: str, name_b: str) -> None:
    """Check that two tensors have the same shape."""
    if a.shape != b.shape:
        raise ValueError(
            f"{name_a} and {name_b} must have the same shape, got {list(a.shape)} and "
            f"{list(b.shape)}"
        )


def check_fusion_inputs(
    filtered: torch.Tensor, depth: torch.Tensor, amplitude: torch.Tensor
) -> None:
    """The inputs of an amplitude fusion: (B, 1, H, W) depth, amplitude and filtered depth."""
    check_image(depth, "depth", 1)
    check_image(amplitude, "amplitude", 1)
    check_same_shape(filtered, depth, "filtered", "depth")
    check_same_shape(amplitude, depth, "amplitude", "depth")


def check_taps(taps: torch.Tensor) -> None:
    """Check FIR taps: a non-empty, finite, floating 1-D tensor."""
    if taps.dim() != 1 or taps.numel() == 0:
        raise ValueError(f"taps must be a non-empty 1-D sequence, got shape {list(taps.shape)}")
    if not taps.is_floating_point():
        raise ValueError(f"taps must be floating point, got dtype {taps.dtype}")
    if not bool(torch.isfinite(taps).all()):
        bad = [i for i, v in enumerate(torch.isfinite(taps).tolist()) if not v]
        raise ValueError(
            f"taps must be finite, got non-finite values at indices {bad}: "
            f"{[float(taps[i]) for i in bad]}"
        )


def normalize_dims(dim) -> tuple[int, ...]:
    """Turn ``-1``, ``-2``, ``3``, ``2`` or a tuple of them into a sorted tuple from {-2, -1}."""
    dims = (dim,) if isinstance(dim, int) and not isinstance(dim, bool) else dim
    try:
        dims = tuple(dims)
    except TypeError:
        raise ValueError(f"dim must be -1, -2 or (-2, -1), got {dim!r}") from None
    out = []
    for d in dims:
        if isinstance(d, bool) or not isinstance(d, int) or d not in (-1, -2, 2, 3):
            raise ValueError(
                f"dim must be -1 (width), -2 (height) or (-2, -1) for (B, C, H, W) input, "
                f"got {dim!r}"
            )
        out.append(d - 4 if d >= 0 else d)
    if not out or len(set(out)) != len(out):
        raise ValueError(f"dim must name -1 and/or -2 once each, got {dim!r}")
    return tuple(sorted(out))
