"""An independent, deliberately simple BVH forward kinematics for tests.

It shares no code with jaxstyle: its own header walk, np.loadtxt for the motion block, and
scipy rotations composed joint by joint as 4x4-free (R, t) pairs. Good enough for well-formed
files, which is all the shared data is.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def reference_fk(path):
    """Global joint positions ``(T, J, 3)`` and the end sites' ``(T, E, 3)`` of a BVH file."""
    text = open(path).read()
    head, _, tail = text.partition("MOTION")
    tokens = head.replace("{", " { ").replace("}", " } ").split()[1:]  # drop HIERARCHY
    joints = []  # dicts: name, parent, offset, channels
    ends = []  # (parent, offset)
    stack, current, in_end = [], None, False
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        if tok in ("ROOT", "JOINT"):
            k = tokens.index("{", i)
            joints.append(dict(name=" ".join(tokens[i + 1:k]), parent=stack[-1] if stack else -1, offset=None,
                               channels=[]))
            current, in_end, i = len(joints) - 1, False, k
            continue
        if tok == "End":
            ends.append([stack[-1], None])
            in_end = True
            i += 2
            continue
        if tok == "{":
            stack.append(current if not in_end else None)
        elif tok == "}":
            stack.pop()
            in_end = False
        elif tok == "OFFSET":
            off = np.array([float(x) for x in tokens[i + 1:i + 4]])
            if in_end:
                ends[-1][1] = off
            else:
                joints[current]["offset"] = off
            i += 3
        elif tok == "CHANNELS":
            n = int(tokens[i + 1])
            joints[current]["channels"] = tokens[i + 2:i + 2 + n]
            i += 1 + n
        i += 1
    lines = tail.strip().split("\n")
    n_frames = int(lines[0].split(":")[1])
    data = np.loadtxt(lines[2:2 + n_frames], ndmin=2)
    col = 0
    g_rot, g_pos = [], []
    for j in joints:
        local_t = np.tile(j["offset"], (len(data), 1))
        rot = Rotation.identity(len(data))
        for c in j["channels"]:
            if c.endswith("position"):
                local_t[:, "XYZ".index(c[0])] = data[:, col]
            else:
                rot = rot * Rotation.from_euler(c[0], data[:, col, None], degrees=True)
            col += 1
        if j["parent"] < 0:
            g_rot.append(rot)
            g_pos.append(local_t)
        else:
            p = j["parent"]
            g_pos.append(g_pos[p] + g_rot[p].apply(local_t))
            g_rot.append(g_rot[p] * rot)
    end_pos = [g_pos[p] + g_rot[p].apply(np.tile(off, (len(data), 1))) for p, off in ends]
    return np.stack(g_pos, axis=1), np.stack(end_pos, axis=1) if end_pos else np.zeros((len(data), 0, 3))
