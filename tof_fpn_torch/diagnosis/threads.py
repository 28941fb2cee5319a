"""Independent pieces of a diagnosis (candidate fits, bootstrap replicates, backward-pass
refits) run in Python threads when torch has more than one thread to give."""

from __future__ import annotations

import torch

__all__ = ["map_threads"]


def map_threads(fn, items: list) -> list:
    """``[fn(x) for x in items]``; with more than one torch thread, the items run in that many
    Python threads of one torch thread each (the candidates are independent fits of small
    images, where one fit cannot use two cores: its ops are too small, autograd and the kernels
    release the GIL). The same fits in the same order either way; only floating-point sums
    may differ in their last bits, as with any change of the torch thread count."""
    n = torch.get_num_threads()
    if n < 2 or len(items) < 2:
        return [fn(x) for x in items]
    from concurrent.futures import ThreadPoolExecutor

    torch.set_num_threads(1)
    try:
        with ThreadPoolExecutor(max_workers=n) as ex:
            return list(ex.map(fn, items))
    finally:
        torch.set_num_threads(n)
