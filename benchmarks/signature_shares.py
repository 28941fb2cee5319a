"""The signature shares (``tof_fpn_torch.diagnosis.signature``) of the baseline's misfit on
development recordings of the form-shifted generator: how much of it is fine in space (the
relative amplitude, and the phasor), sporadic in time, and common to a frame's pixels, for the
planted effects whose neighbours a spread could stand in for. Writes
docs/figures/signature_shares.json and prints one line per recording.

    python benchmarks/signature_shares.py            # the development seeds cited in the docs
"""

from __future__ import annotations

import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
import bench_form_shifted as bfs  # noqa: E402 (a sibling script)

#: (effect, form, seed, scene model, factor): the development recordings of seeds 13000 on
CASES = (
    ("pixel_gain", "A", 13016, "corner", 1.0),
    ("pixel_gain", "A", 13017, "steps", 2.0),
    ("pixel_gain", "B", 13018, "steps", 1.0),
    ("pixel_gain", "B", 13019, "solids", 2.0),
    ("impulsive_pixels", "A", 13020, "corner", 1.0),
    ("impulsive_pixels", "B", 13022, "steps", 1.0),
    ("multipath", "A", 13032, "corner", 1.0),
    ("multipath", "A", 13033, "steps", 2.0),
    ("multipath", "B", 13034, "steps", 1.0),
    ("multipath", "B", 13035, "solids", 2.0),
    ("temporal_drift", "A", 13044, "corner", 1.0),
    ("temporal_drift", "B", 13046, "steps", 1.0),
    ("vignetting", "A", 13048, "corner", 1.0),
)


def one(case) -> dict:
    torch.set_num_threads(1)
    from tof_fpn_torch.diagnosis.model import predict
    from tof_fpn_torch.diagnosis.run import _baseline, _fit_baseline, observe
    from tof_fpn_torch.diagnosis.signature import common_share, fine_share, sporadic_share
    from tof_fpn_torch.io import Recording

    effect, form, seed, kind, factor = case
    gen, scene = bfs.record(bfs.make_job(effect, form, factor, seed, kind, (bfs.H, bfs.W, bfs.T)))
    rec = Recording(torch.from_numpy(gen["depth"]), torch.from_numpy(gen["amplitude"]), gen["meta"])
    obs = observe(rec, scene)
    base, ctx, _ = _fit_baseline(_baseline(obs, None), obs)
    with torch.no_grad():
        p = predict(base, obs, scene=ctx.scene)
    r4 = lambda x: None if x is None else round(x, 4)  # noqa: E731
    return {
        "effect": effect,
        "form": form,
        "seed": seed,
        "scene": kind,
        "factor": factor,
        "fine_amplitude": r4(fine_share(obs, ctx, p)),
        "fine_phasor": r4(fine_share(obs, ctx, p, phasor=True)),
        "sporadic": r4(sporadic_share(obs, ctx, p)),
        "common": r4(common_share(obs, ctx, p)),
    }


def main() -> None:
    workers = int(sys.argv[1]) if len(sys.argv) > 1 else 2
    with ProcessPoolExecutor(max_workers=workers) as ex:
        out = list(ex.map(one, CASES))
    for r in out:
        print(json.dumps(r))
    path = HERE.parent / "docs/figures/signature_shares.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
