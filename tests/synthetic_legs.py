"""A small synthetic skeleton with two legs (hip, knee, ankle, toe), a spine and wrists, in
centimetres, shared by the metrics and foot-IK tests (no motion capture needed)."""

from __future__ import annotations

import numpy as np

NAMES = ("Hips", "Spine", "LeftWrist", "RightWrist", "LeftHip", "LeftKnee", "LeftAnkle", "LeftToe",
         "RightHip", "RightKnee", "RightAnkle", "RightToe")
PARENTS = np.array([-1, 0, 1, 1, 0, 4, 5, 6, 0, 8, 9, 10])
OFFSETS = np.array([[0, 0, 0], [0, 30, 0], [30, 20, 0], [-30, 20, 0],
                    [10, 0, 0], [0, -40, 0], [0, -40, 0], [0, -8, 15],
                    [-10, 0, 0], [0, -40, 0], [0, -40, 0], [0, -8, 15]], dtype=np.float64)
