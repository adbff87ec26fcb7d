"""Where jaxstyle finds motion capture on disk.

The shared sample (and, later, full datasets) is found through the ``JAXSTYLE_MOCAP``
environment variable, defaulting to ``../shared/mocap`` beside the project checkout.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

ENV_VAR = "JAXSTYLE_MOCAP"


def default_mocap_dir() -> Path:
    """``$JAXSTYLE_MOCAP`` if set, else ``<checkout>/../shared/mocap``, else ``./../shared/mocap``."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).expanduser()
    beside_checkout = Path(__file__).resolve().parents[2] / "shared" / "mocap"
    if beside_checkout.is_dir():
        return beside_checkout
    return Path.cwd().parent / "shared" / "mocap"


def mocap_dir(required: bool = True) -> Path | None:
    """The motion capture folder; a clear error (or ``None`` when not ``required``) if it is absent."""
    path = default_mocap_dir()
    if path.is_dir():
        return path
    if not required:
        return None
    raise FileNotFoundError(
        f"motion capture folder {path} not found; set {ENV_VAR} to the folder holding the BVH files")


def read_phase_labels(bvh_path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Hand-cleaned PFNN phase labels of a capture: ``(phase_T, labelled_T)``.

    Reads ``<name>.phase`` (one phase in ``[0, 1)`` per frame) and ``<name>_footsteps.txt``
    beside ``<name>.bvh``. A frame is labelled only between the first and last footstep listed
    (clipped to the clip); outside that range the file holds 0 meaning "unlabelled", and a file
    with a single footstep has no labelled frame.
    """
    from jaxstyle.errors import MotionDataError

    bvh_path = Path(bvh_path)
    stem = bvh_path.with_suffix("")
    phase_path, steps_path = Path(f"{stem}.phase"), Path(f"{stem}_footsteps.txt")
    for p in (phase_path, steps_path):
        if not p.is_file():
            raise FileNotFoundError(f"{p} not found (phase labels of {bvh_path})")
    try:
        phase = np.loadtxt(phase_path, dtype=np.float64, ndmin=1)
        steps = np.array([int(tok) for tok in steps_path.read_text().split()], dtype=np.int64)
    except ValueError as e:
        raise MotionDataError(f"cannot read phase labels: {e}", phase_path) from None
    if phase.ndim != 1 or not np.isfinite(phase).all() or (phase < 0).any() or (phase >= 1).any():
        raise MotionDataError("phase labels must be one finite value in [0, 1) per line", phase_path)
    labelled = np.zeros(len(phase), dtype=bool)
    if len(steps) >= 2:
        labelled[max(int(steps.min()), 0):min(int(steps.max()), len(phase) - 1) + 1] = True
    return phase, labelled
