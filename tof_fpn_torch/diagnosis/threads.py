"""Independent pieces of a diagnosis (candidate fits, bootstrap replicates, backward-pass
refits) run in Python threads when torch has more than one thread to give."""

from __future__ import annotations

import torch

__all__ = ["map_threads"]


def map_threads(fn, items: list, first=None) -> list:
    """``[fn(x) for x in items]``; with more than one torch thread, the items run in that many
    Python threads of one torch thread each (the candidates are independent fits of small
    images, where one fit cannot use two cores: its ops are too small, autograd and the kernels
    release the GIL). The same fits in the same order either way; only floating-point sums
    may differ in their last bits, as with any change of the torch thread count. ``first``: a
    predicate of the items to start first (the slow ones, so that no thread waits at the end);
    the results keep the order of ``items``."""
    n = torch.get_num_threads()
    if n < 2 or len(items) < 2:
        return [fn(x) for x in items]
    from concurrent.futures import ThreadPoolExecutor

    idx = list(range(len(items)))
    if first is not None:
        idx.sort(key=lambda i: not first(items[i]))  # stable: the rest keep their order
    torch.set_num_threads(1)
    try:
        with ThreadPoolExecutor(max_workers=n) as ex:
            done = list(ex.map(lambda i: fn(items[i]), idx))
        out = [None] * len(items)
        for i, r in zip(idx, done, strict=True):
            out[i] = r
        return out
    finally:
        torch.set_num_threads(n)
