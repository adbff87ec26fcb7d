"""The :class:`Motion` value: a skeleton and its animation, as NumPy arrays.

Shapes use ``T`` frames, ``J`` joints and ``E`` end sites. Every operation in jaxstyle returns a
new ``Motion`` (it is frozen); nothing is modified in place.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from jaxstyle.errors import MotionDataError

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")


@dataclasses.dataclass(frozen=True, eq=False)
class Motion:
    """A skeleton and its motion.

    Attributes:
      names: ``J`` joint names, parents before children (BVH order).
      parents: ``(J,)`` int parent index of each joint, ``-1`` for a root.
      offsets: ``(J, 3)`` rest offsets from the parent (BVH ``OFFSET``), in file units.
      rotations: ``(T, J, 4)`` local joint rotations as unit quaternions ``(w, x, y, z)``.
      local_positions: ``(T, J, 3)`` local translation of each joint in its parent's frame:
        the offset, with the components that the joint animates (position channels, on the root
        or on any other joint) replaced by the channel values.
      fps: frames per second.
      channels: per joint, its BVH channel names in file order (used to write the file back;
        an empty tuple for a joint without channels).
      end_site_parents: ``(E,)`` the joint each ``End Site`` hangs from.
      end_site_offsets: ``(E, 3)`` the end sites' offsets.
      source: where the motion came from (a file path), used in error messages.
      joint_map: a :class:`jaxstyle.motion.skeleton.JointMap` (role -> joints) for a skeleton whose
        feet, hips, shoulders or hands are not found by name; the finders and mirroring use it.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    rotations: np.ndarray
    local_positions: np.ndarray
    fps: float
    channels: tuple[tuple[str, ...], ...]
    end_site_parents: np.ndarray
    end_site_offsets: np.ndarray
    source: str | None = None
    joint_map: object | None = None  # jaxstyle.motion.skeleton.JointMap (kept untyped: skeleton imports clip's layer)

    def __post_init__(self):
        j = len(self.names)
        t = self.rotations.shape[0] if self.rotations.ndim == 3 else -1
        expected = {
            "parents": (self.parents, (j,)),
            "offsets": (self.offsets, (j, 3)),
            "rotations": (self.rotations, (t, j, 4)),
            "local_positions": (self.local_positions, (t, j, 3)),
            "end_site_offsets": (self.end_site_offsets, (len(self.end_site_parents), 3)),
        }
        for field, (value, shape) in expected.items():
            if value.shape != shape:
                raise MotionDataError(f"Motion.{field} has shape {value.shape}, expected {shape}", self.source)
        if len(self.channels) != j:
            raise MotionDataError(f"Motion.channels lists {len(self.channels)} joints, expected {j}", self.source)
        if np.any(self.parents >= np.arange(j)) or np.any(self.parents < -1):
            raise MotionDataError("Motion.parents must list each parent before its children", self.source)
        if not self.fps > 0:
            raise MotionDataError(f"Motion.fps must be positive, got {self.fps}", self.source)

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def duration(self) -> float:
        """Length in seconds (``num_frames / fps``)."""
        return self.num_frames / self.fps

    @property
    def root_positions(self) -> np.ndarray:
        """``(T, 3)`` translation of the (first) root joint."""
        return self.local_positions[:, 0]

    def joint_index(self, name: str) -> int:
        """Index of the joint called ``name``; a clear error names the joints there are."""
        try:
            return self.names.index(name)
        except ValueError:
            raise MotionDataError(f"no joint named {name!r}; joints are {', '.join(self.names)}", self.source) from None

    def joint_indices(self, names: Sequence[str]) -> np.ndarray:
        return np.array([self.joint_index(n) for n in names], dtype=np.int64)

    def frames(self, start: int | None = None, stop: int | None = None, step: int | None = None) -> "Motion":
        """The motion restricted to ``frames[start:stop:step]`` (same skeleton and fps unless ``step``)."""
        sl = slice(start, stop, step)
        fps = self.fps / (step or 1)
        return dataclasses.replace(self, rotations=self.rotations[sl], local_positions=self.local_positions[sl],
                                   fps=fps)

    def replace(self, **changes) -> "Motion":
        """A copy with the given fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)
