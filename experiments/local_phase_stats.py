"""Local-phase quality with and without the amplitude bound of the fit (README table).

    python experiments/local_phase_stats.py [clips relative to the mocap folder ...]

For each clip and bound it prints the share of frames whose phase advances at a plausible rate
(0.2-4.5 Hz) and the ratio of the 99th percentile of the Eq. 1 feature magnitude to its median
(spikes in the features the 2022 gating network reads).
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

import jaxstyle as js
from jaxstyle.labels.local_phase import MAX_AMPLITUDE, LocalPhaseConfig, local_phases
from jaxstyle.labels.sinusoid import SinusoidConfig


@dataclasses.dataclass(frozen=True)
class Config:
    clips: tuple[str, ...] = ("100style/Angry/Angry_FW.bvh", "100style/Chicken/Chicken_FR.bvh",
                              "100style/Drunk/Drunk_SW.bvh", "100style/Aeroplane/Aeroplane_SR.bvh")
    bounds: tuple[float | None, ...] = (None, 3.0, MAX_AMPLITUDE)


def stats(motion: js.Motion, bound: float | None) -> tuple[float, float]:
    res = local_phases(motion, LocalPhaseConfig(sinusoid=SinusoidConfig(max_amplitude=bound)))
    advance_hz = np.mod(np.diff(res.phase, axis=0), 1.0) * motion.fps
    plausible = float(np.mean((advance_hz > 0.2) & (advance_hz < 4.5)))
    magnitude = np.linalg.norm(res.features, axis=-1)
    return plausible, float(np.percentile(magnitude, 99) / max(np.median(magnitude), 1e-12))


def main(config: Config = Config()) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clips", nargs="*", default=list(config.clips))
    args = parser.parse_args()
    print(f"{'clip':40s}{'max_amplitude':>14s}{'plausible advance':>19s}{'feature p99/median':>20s}")
    for clip in args.clips:
        motion = js.read_bvh(js.mocap_dir() / clip)
        for bound in config.bounds:
            plausible, spike = stats(motion, bound)
            print(f"{clip:40s}{str(bound):>14s}{plausible:19.2f}{spike:20.1f}")


if __name__ == "__main__":
    main()
