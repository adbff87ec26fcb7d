"""Where jaxstyle finds motion capture on disk.

The shared sample (and, later, full datasets) is found through the ``JAXSTYLE_MOCAP``
environment variable, defaulting to ``../shared/mocap`` beside the project checkout.
"""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "JAXSTYLE_MOCAP"


def default_mocap_dir() -> Path:
    """``$JAXSTYLE_MOCAP`` if set, else ``<checkout>/../shared/mocap``, else ``./../shared/mocap``."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).expanduser()
    beside_checkout = Path(__file__).resolve().parents[3] / "shared" / "mocap"
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
