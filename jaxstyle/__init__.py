"""jaxstyle: style-controllable character locomotion in JAX.

Reimplements Mason et al. 2018 (few-shot PFNN residual adapters) and Mason, Starke & Komura 2022
(local motion phases with FiLM). This module re-exports the public API.
"""

from jaxstyle import quat
from jaxstyle.bvh import format_bvh, parse_bvh, read_bvh, write_bvh
from jaxstyle.data import default_mocap_dir, mocap_dir
from jaxstyle.errors import JaxstyleError, MotionDataError
from jaxstyle.kinematics import (
    bone_lengths,
    facing_directions,
    forward_kinematics,
    global_positions,
    global_transforms,
    rest_positions,
    root_trajectory,
    skeleton_height,
)
from jaxstyle.motion import Motion
from jaxstyle.skeleton import find_hips_and_shoulders, mirror_pairs
from jaxstyle.transform import mirror, resample, rotate, scale, set_up_axis

__version__ = "0.1.0"

__all__ = [
    "JaxstyleError",
    "Motion",
    "MotionDataError",
    "bone_lengths",
    "default_mocap_dir",
    "facing_directions",
    "find_hips_and_shoulders",
    "format_bvh",
    "forward_kinematics",
    "global_positions",
    "global_transforms",
    "mirror",
    "mirror_pairs",
    "mocap_dir",
    "parse_bvh",
    "quat",
    "read_bvh",
    "resample",
    "rest_positions",
    "root_trajectory",
    "rotate",
    "scale",
    "set_up_axis",
    "skeleton_height",
    "write_bvh",
]
