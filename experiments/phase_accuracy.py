"""Automatic global phase vs the hand-cleaned PFNN labels, and the effect of the contact moment.

    python experiments/phase_accuracy.py [--mocap DIR]

Prints, for each definition of the start of a contact (and for a few speed thresholds), the
median and 90th-percentile circular error in cycles over the labelled frames of the flat-ground
captures (original and mirrored) and, separately, of the stairs capture.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

import jaxstyle as js
from jaxstyle.labels import contacts, phase


@dataclasses.dataclass(frozen=True)
class Config:
    flat: tuple[str, ...] = ("NewCaptures01_000", "NewCaptures10_000", "NewCaptures11_000")
    stairs: tuple[str, ...] = ("WalkingUpSteps09_000",)
    speed_thresholds: tuple[float, ...] = (0.08, 0.1, 0.12, 0.14, 0.16)


def files(folder: Path, names: tuple[str, ...]) -> list[Path]:
    return [folder / f"{n}{suffix}.bvh" for n in names for suffix in ("", "_mirror")]


def footstep_config(contact_moment: str | None = None, min_lift: float | None = None,
                    merge_window: float | None = None, **contact_fields) -> phase.FootstepConfig:
    """The default :class:`jaxstyle.labels.phase.FootstepConfig` with the given fields changed
    (``contact_fields``: those of its :class:`jaxstyle.labels.contacts.ContactConfig`)."""
    base = phase.FootstepConfig()
    changes = {k: v for k, v in dict(contact_moment=contact_moment, min_lift=min_lift,
                                     merge_window=merge_window).items() if v is not None}
    return dataclasses.replace(base, contacts=dataclasses.replace(base.contacts, **contact_fields), **changes)


def summary(paths: list[Path], **kwargs) -> tuple[float, float]:
    errors = np.concatenate([phase.label_errors(p, footstep_config(**kwargs)) for p in paths])
    return float(np.median(errors)), float(np.percentile(errors, 90))


def step_offsets(paths: list[Path], **kwargs) -> np.ndarray:
    """Detected minus labelled footstep frames, for each labelled footstep inside its clip."""
    out = []
    for p in paths:
        motion = js.read_bvh(p)
        labelled = phase.read_footsteps(str(p)[:-4] + "_footsteps.txt")  # 0-based (the files count from 1)
        if len(labelled) < 2:
            continue
        left, right = phase.footsteps(motion, footstep_config(**kwargs))
        for i, frame in enumerate(labelled):  # footsteps alternate right, left, right, ...
            detected = right if i % 2 == 0 else left
            if 0 <= frame < motion.num_frames and len(detected):
                out.append(int(detected[np.argmin(np.abs(detected - frame))] - frame))
    return np.array(out)


def main(config: Config = Config()) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mocap", type=Path, default=None, help="motion capture folder (default $JAXSTYLE_MOCAP)")
    args = parser.parse_args()
    folder = (args.mocap or js.mocap_dir()) / "pfnn_excerpt"
    flat, stairs = files(folder, config.flat), files(folder, config.stairs)

    print("Global phase error (cycles): median / 90th percentile over labelled frames")
    print(f"flat ground: {len(flat)} files, stairs: {len(stairs)} files (originals and mirrors)\n")
    print(f"{'contact moment':16s}{'flat median':>12s}{'flat p90':>10s}{'stairs median':>15s}{'stairs p90':>12s}"
          "   footstep offsets (frames at 120 fps, detected - labelled)")
    for moment in contacts.CONTACT_MOMENTS:
        fm, fp = summary(flat, contact_moment=moment)
        sm, sp = summary(stairs, contact_moment=moment)
        mark = "  (default)" if moment == phase.DEFAULT_CONTACT_MOMENT else ""
        off = step_offsets(flat + stairs, contact_moment=moment)
        print(f"{moment:16s}{fm:12.3f}{fp:10.3f}{sm:15.3f}{sp:12.3f}   {' '.join(f'{o:+d}' for o in off)}{mark}")

    print(f"\nSpeed threshold (m/s), contact moment '{phase.DEFAULT_CONTACT_MOMENT}': flat median / p90")
    for v in config.speed_thresholds:
        fm, fp = summary(flat, speed_threshold=v)
        print(f"  v_max={v:<6g} {fm:.3f} / {fp:.3f}")
    fm, fp = summary(flat, release_speed=None)
    print(f"  no hysteresis (v_max={phase.DEFAULT_SPEED_THRESHOLD_M_S:g} both ways): {fm:.3f} / {fp:.3f}")

    print("\nContact rule (jaxstyle.labels.contacts): flat median / p90, stairs median / p90")
    old = dict(rule="paper2022", speed_threshold=0.15, release_speed=0.5, min_lift=0.03)
    for label, kwargs in (("scaled (default)", {}),
                          ("paper2022 units, thresholds 0.15 / 0.5 m/s, lift 0.03 m (the earlier default)", old),
                          ("the same, no merging of landings of both feet", dict(old, merge_window=0.0))):
        fm, fp = summary(flat, **kwargs)
        sm, sp = summary(stairs, **kwargs)
        print(f"  {label}: {fm:.3f} / {fp:.3f}, {sm:.3f} / {sp:.3f}")


if __name__ == "__main__":
    main()
