"""Benchmark: simulate 200 frames of 204 x 204 with the raw-level ToF simulator (CPU).

Peer, run side by side in the same process: a NumPy implementation of the same chain (photons,
Gaussian shot noise, column FPN, read noise, ADC, eq. (1) decoding), float32, same sizes. Times are
medians of ``--repeats`` runs; the machine may be shared, so the ratio is the robust figure.

    python benchmarks/bench_sim.py [--frames 200] [--size 204] [--repeats 5] [--threads 2]
    python benchmarks/bench_sim.py --laws     # the noise / FPN laws and the Table I calibration
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np
import torch

from tof_fpn_torch.sim import (
    SPEED_OF_LIGHT_AIR,
    Camera,
    Photons,
    ReadoutFPN,
    Simulation,
    synthetic_scene,
)


def numpy_sim(depth, refl, cam: Camera, photons: Photons, fpn: ReadoutFPN, frames, rng):
    """The default chain (without impulsive pixels) in NumPy, float32."""
    n = cam.n_phases
    d = depth.astype(np.float32)
    r = refl.astype(np.float32)
    t, k = cam.integration_time, photons.responsivity
    active = (t * k) * r * (cam.illumination_power / (photons.solid_angle * d * d))
    ambient = (t * k * cam.ambient_irradiance) * r
    phi = d * (4 * math.pi * cam.modulation_frequency / SPEED_OF_LIGHT_AIR)
    th = np.arange(n) * 2 * math.pi / n
    cos_t = np.cos(th).astype(np.float32).reshape(1, n, 1, 1)
    sin_t = np.sin(th).astype(np.float32).reshape(1, n, 1, 1)
    mean = (active + ambient) + active * photons.modulation_contrast * (
        np.cos(phi) * cos_t - np.sin(phi) * sin_t
    )
    mean = np.maximum(mean, 0).astype(np.float32)
    noise = rng.standard_normal((frames, n) + d.shape[2:], dtype=np.float32)
    s = mean + noise * np.sqrt(mean)
    off, gain = fpn.patterns(n, d.shape[3], torch.device("cpu"), torch.float32)
    s = s * gain.numpy().reshape(1, n, 1, -1) + off.numpy().reshape(1, n, 1, -1)
    s += cam.read_noise * rng.standard_normal(s.shape, dtype=np.float32)
    s = np.clip(np.round(np.minimum(s, cam.full_well) / cam.conversion_gain), 0, cam.max_code)
    re = np.tensordot(np.cos(th).astype(np.float32), s, axes=([0], [1]))
    im = -np.tensordot(np.sin(th).astype(np.float32), s, axes=([0], [1]))
    phase = np.mod(np.arctan2(im, re), 2 * math.pi)
    depth_out = phase * (SPEED_OF_LIGHT_AIR / (4 * math.pi * cam.modulation_frequency))
    return depth_out, np.hypot(re, im) * (2 / n), s.mean(axis=1)


def median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def laws() -> None:
    """Print the measured noise law, FPN growth and eq. (10) calibration figures of the docs."""
    from tof_fpn_torch.analysis.metrics import psnr
    from tof_fpn_torch.sim import (
        DepthFPN,
        depth_noise_vs_amplitude,
        fpn_error_vs_amplitude,
        noise_lambda,
    )

    cam = Camera(
        integration_time=1e-3,
        ambient_irradiance=20.0,
        full_well=4e6,
        conversion_gain=100.0,
        adc_bits=16,
    )
    c = depth_noise_vs_amplitude(Simulation(cam).without("readout_fpn"), seed=1)
    ratio = (torch.sqrt(noise_lambda(cam, c.offset)) / c.amplitude / c.value).numpy()
    print(
        f"ambient-dominated: A {float(c.amplitude.min()):.0f}..{float(c.amplitude.max()):.0f} DN, "
        f"log-log slope of sigma_D vs A = {c.slope:.3f}; eq. (2) prediction / measured = "
        f"{ratio.min():.3f}..{ratio.max():.3f}"
    )
    cam2 = Camera(
        integration_time=200e-6, ambient_irradiance=0.0, read_noise=0.0, full_well=2e6, adc_bits=16
    )
    c2 = depth_noise_vs_amplitude(Simulation(cam2).without("readout_fpn"), seed=2)
    print(f"active-shot-limited: log-log slope = {c2.slope:.3f} (1/sqrt(A) expected)")
    f = fpn_error_vs_amplitude(Simulation(Camera(integration_time=100e-6)))
    for i in (0, len(f.value) // 2, len(f.value) - 1):
        print(
            f"raw FPN: A = {float(f.amplitude[i]):7.1f} DN -> mean |depth error| = "
            f"{float(f.value[i]) * 100:.2f} cm"
        )
    # eq. (10) reconstruction on the synthetic scene vs Table I's FPN-only input 24.51 dB
    vals = []
    for seed in range(5):
        s = synthetic_scene(seed=seed)
        vals.append(float(psnr(DepthFPN()(s.depth, s.amplitude), s.depth)))
    print(
        "eq. (10) FPN-only input PSNR, synthetic_scene seeds 0-4: "
        + ", ".join(f"{v:.2f}" for v in vals)
        + " dB (paper, Table I: 24.51 dB)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--size", type=int, default=204)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--laws", action="store_true", help="print the noise/FPN law figures instead")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    if args.laws:
        laws()
        return
    scene = synthetic_scene(args.size, args.size, seed=0)
    sim = Simulation(Camera(integration_time=100e-6))
    torch_t = median_time(lambda: sim.run(scene, args.frames, seed=0), args.repeats)
    rng = np.random.default_rng(0)
    d, r = scene.depth.numpy(), scene.reflectance.numpy()
    photons, fpn = sim.term("photons"), sim.term("readout_fpn")
    numpy_t = median_time(
        lambda: numpy_sim(d, r, sim.camera, photons, fpn, args.frames, rng), args.repeats
    )
    # agreement of the two implementations (different random streams: compare statistics)
    out = sim.run(scene, args.frames, seed=0)
    nd, na, _ = numpy_sim(d, r, sim.camera, photons, fpn, args.frames, rng)
    print(
        f"frames={args.frames} size={args.size}x{args.size} N={sim.camera.n_phases} "
        f"threads={args.threads} repeats={args.repeats} (median)"
    )
    print(f"torch simulator : {torch_t:.3f} s  ({args.frames / torch_t:.0f} frames/s)")
    print(f"numpy peer      : {numpy_t:.3f} s  ({args.frames / numpy_t:.0f} frames/s)")
    print(f"speed ratio numpy/torch: {numpy_t / torch_t:.2f}x")
    print(
        "mean amplitude torch/numpy: "
        f"{float(out.amplitude.mean()):.3f} / {float(na.mean()):.3f} DN; "
        f"mean depth {float(out.depth.mean()):.4f} / {float(nd.mean()):.4f} m"
    )
    print(f"under 2 s: {'yes' if torch_t < 2.0 else 'NO'}")


if __name__ == "__main__":
    main()
