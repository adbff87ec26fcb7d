"""Motion: the ``Motion`` clip, BVH reading and writing, quaternions, forward kinematics, transforms,
skeleton roles and the character frame."""

from jaxstyle._lazy import lazy_module
from jaxstyle.motion.clip import POSITION_CHANNELS, ROTATION_CHANNELS, Motion

__all__ = ["Motion", "POSITION_CHANNELS", "ROTATION_CHANNELS"]

__getattr__, __dir__ = lazy_module(__name__, ["bvh", "character_frame", "clip", "kinematics", "quat", "skeleton",
                                              "transform"])
