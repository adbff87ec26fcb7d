"""Local-phase extraction speed: the vectorised JAX fit against a scipy curve_fit loop.

    python benchmarks/phases.py [--file 100style/Angry/Angry_FW.bvh] [--loop-frames 200]

Measured in one run on one clip, 4 bones (hands and feet):

* ``local_phases``: the whole labelling from a parsed clip (FK, contacts, sources, normalisation,
  Butterworth, fit, features), after a warm-up call that pays JAX compilation;
* ``fit_sinusoids`` alone on the same sources;
* the same fit done the usual way, ``scipy.optimize.curve_fit`` window by window (one start, the
  bounds of the paper), on ``--loop-frames`` frames x 4 bones, scaled to frames per second.

Then the ratio fit/loop, and the time the whole 100STYLE dataset (about 4 million frames)
would take at the measured ``local_phases`` rate.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np

import jaxstyle as js
from jaxstyle.labels import local_phase, sinusoid

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.reference_sinusoid import fit_window  # noqa: E402  (the test reference, reused)

DATASET_FRAMES = 4_000_000


def best_of(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--file", default="100style/Angry/Angry_FW.bvh", help="path relative to the mocap folder")
    parser.add_argument("--loop-frames", type=int, default=200, help="frames fitted by the curve_fit loop")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    motion = js.read_bvh(js.mocap_dir() / args.file)
    fps = motion.fps
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"jax {jax.__version__} on {jax.devices()[0].platform}")
    print(f"clip: {args.file}, {motion.num_frames} frames at {fps:g} fps, 4 bones\n")

    result = local_phase.local_phases(motion)  # warm-up: compiles the fit
    t_full = best_of(lambda: local_phase.local_phases(motion), args.repeats)
    src = result.source
    amax = local_phase.MAX_AMPLITUDE
    t_fit = best_of(lambda: sinusoid.fit_sinusoids(src, fps, sinusoid.SinusoidConfig(max_amplitude=amax)), args.repeats)

    half = sinusoid.window_frames(fps) // 2
    tau = (np.arange(2 * half + 1) - half) / fps
    frames = np.linspace(half, motion.num_frames - half - 1, args.loop_frames).astype(int)
    t0 = time.perf_counter()
    for t in frames:
        for b in range(src.shape[1]):
            fit_window(tau, src[t - half:t + half + 1, b], a_max=amax, starts=(1.0,))
    t_loop = (time.perf_counter() - t0) / len(frames) * motion.num_frames

    fps_full, fps_fit, fps_loop = (motion.num_frames / t for t in (t_full, t_fit, t_loop))
    print(f"local_phases (whole labelling) {fps_full:12,.0f} frames/s")
    print(f"fit_sinusoids (JAX, vectorised) {fps_fit:11,.0f} frames/s")
    print(f"curve_fit loop (scipy)         {fps_loop:12,.0f} frames/s  ({len(frames)} frames x 4 bones timed)")
    print(f"\nratio fit / curve_fit loop: {fps_fit / fps_loop:,.0f}x   "
          f"(whole labelling / loop: {fps_full / fps_loop:,.0f}x)")
    print(f"whole 100STYLE (~{DATASET_FRAMES / 1e6:g} M frames) at the local_phases rate: "
          f"{DATASET_FRAMES / fps_full / 60:.1f} min")


if __name__ == "__main__":
    main()
