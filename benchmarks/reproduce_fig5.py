"""Reproduce Fig. 5 of Georgiev et al. (IEEE SAS 2015): passband ripple (dB) against rho.

Odd orders {5, 9, 17, 21, 31, 41, 53} and even orders {8, 12, 20, 28, 40, 52}, 50 values of rho in
(0, 1/6]. Writes ``fig5.csv`` and ``fig5.png`` to ``--out``, and checks the paper's claim that an
even order needs about 10 more orders than an odd one for the same ripple (``fig5_even_vs_odd.csv``):
for every even order and rho, the odd order with the same ripple is interpolated (in dB, linearly in
the order) between designs of all odd orders at that rho.

    python benchmarks/reproduce_fig5.py --out out/fig5
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from tof_fpn_torch.design import design_fpn

ODD = (5, 9, 17, 21, 31, 41, 53)
EVEN = (8, 12, 20, 28, 40, 52)


def ripple_family(orders, rhos):
    """``ripple_db[order_index, rho_index]`` and the order of G actually optimised."""
    db = np.empty((len(orders), len(rhos)))
    g_order = np.empty_like(db, dtype=int)
    for i, n in enumerate(orders):
        for j, rho in enumerate(rhos):
            d = design_fpn(n, float(rho))
            db[i, j], g_order[i, j] = d.ripple_db, d.g_order
    return db, g_order


def equivalent_odd_order(even_db: np.ndarray, odd_orders: np.ndarray, odd_db: np.ndarray) -> float:
    """Odd order (interpolated) whose ripple equals ``even_db``; NaN outside the odd range."""
    # Ripple falls with the order; interpolate the order as a function of the ripple (dB).
    order = np.argsort(odd_db)
    return float(np.interp(even_db, odd_db[order], odd_orders[order], left=np.nan, right=np.nan))


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", type=Path, default=Path("out/fig5"))
    ap.add_argument("--points", type=int, default=50, help="values of rho (default 50)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rhos = np.linspace(1 / 6 / args.points, 1 / 6, args.points)

    t0 = time.perf_counter()
    odd_db, odd_g = ripple_family(ODD, rhos)
    even_db, even_g = ripple_family(EVEN, rhos)
    elapsed = time.perf_counter() - t0
    n_designs = (len(ODD) + len(EVEN)) * len(rhos)
    print(
        f"Fig. 5 family: {n_designs} designs in {elapsed:.2f} s ({1e3 * elapsed / n_designs:.2f} ms each)"
    )

    with open(args.out / "fig5.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["order", "parity", "rho", "ripple_db", "g_order"])
        for orders, db, g, parity in ((ODD, odd_db, odd_g, "odd"), (EVEN, even_db, even_g, "even")):
            for i, n in enumerate(orders):
                for j, rho in enumerate(rhos):
                    w.writerow([n, parity, f"{rho:.6f}", f"{db[i, j]:.3f}", g[i, j]])

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=False)
    for ax, orders, db, title in (
        (axes[0], ODD, odd_db, "(a) odd orders"),
        (axes[1], EVEN, even_db, "(b) even orders"),
    ):
        for i, n in enumerate(orders):
            ax.plot(rhos, db[i], label=str(n))
        ax.set_xlabel(r"Transition bandwidth parameter $\rho$")
        ax.set_ylabel("Passband ripple (dB)")
        ax.set_title(title)
        ax.set_xlim(0, 0.2)
        ax.set_ylim(-140, 0)
        ax.axhspan(-140, -100, color="0.85", lw=0)
        ax.text(0.005, -135, "below -100 dB: float64 limit (RIPPLE_FLOOR)", fontsize=7)
        ax.grid(alpha=0.3)
        ax.legend(title="N", fontsize=8)
    fig.suptitle("Fig. 5 reproduced: minimax passband ripple of H = A1 A2 G")
    fig.tight_layout()
    fig.savefig(args.out / "fig5.png", dpi=120)
    plt.close(fig)

    # Even vs odd: equivalent odd order for every even design.
    all_odd = np.arange(5, 62, 2)
    all_odd_db, _ = ripple_family(all_odd, rhos)
    rows = []
    for i, n in enumerate(EVEN):
        gaps = []
        for j in range(rhos.size):
            eq = equivalent_odd_order(even_db[i, j], all_odd, all_odd_db[:, j])
            if even_db[i, j] > -100 and np.isfinite(eq):  # above the float64 floor only
                gaps.append(n - eq)
        gaps = np.array(gaps)
        rows.append((n, len(gaps), np.median(gaps), gaps.min(), gaps.max()))
    with open(args.out / "fig5_even_vs_odd.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["even_order", "n_rho", "median_extra_orders", "min_extra", "max_extra"])
        for r in rows:
            w.writerow([r[0], r[1], f"{r[2]:.2f}", f"{r[3]:.2f}", f"{r[4]:.2f}"])
    print("Extra orders an even design needs over an odd one for the same ripple (over rho):")
    for n, k, med, lo, hi in rows:
        print(f"  N = {n:2d}: median {med:5.2f}  (min {lo:5.2f}, max {hi:5.2f}, {k} values of rho)")
    print(
        f"wrote {args.out / 'fig5.csv'}, {args.out / 'fig5.png'}, {args.out / 'fig5_even_vs_odd.csv'}"
    )


if __name__ == "__main__":
    main()
