"""Joint naming: left/right pairing for mirroring, and finding hips and shoulders by name.

Pairing understands the namings of the data both papers use and their common relatives:

* whole words ``Left``/``Right`` anywhere (100STYLE ``LeftHip``, CMU ``LeftUpLeg``, Mixamo
  ``mixamorig:LeftArm``; also ``left``/``right`` and ``LEFT``/``RIGHT``);
* a single side letter as prefix, suffix or separate token, kept only when the other side's
  name exists: CMU ``LHipJoint``/``RHipJoint`` and ``LThumb``, the 3dsMax-friendly CMU
  ``lhand``/``rhand`` and ``LFingers``, Daz ``lShldr``, ``Bip01 L Thigh``, ``hip_l``, ``Hand.R``.

Names with no side map to themselves (spine, head). A name with ``Left``/``Right`` whose
counterpart is missing is an error, since mirroring such a skeleton cannot be right.
"""

from __future__ import annotations

import re
from typing import Sequence

import numpy as np

from jaxstyle.errors import MotionDataError

_WORD_SWAPS = (("Left", "Right"), ("left", "right"), ("LEFT", "RIGHT"))
_LETTER_SWAP = {"L": "R", "R": "L", "l": "r", "r": "l"}
_SEPARATORS = " _.-:"


def _word_counterpart(name: str) -> str | None:
    for a, b in _WORD_SWAPS:
        if a in name or b in name:
            # Swap through a placeholder so "LeftRight" style names swap both ways.
            return name.replace(a, "\0").replace(b, a).replace("\0", b)
    return None


def _is_side_letter(name: str, i: int, strict: bool) -> bool:
    """Whether ``name[i]`` is a side letter (L, R, l, r) at a token boundary.

    Loose: it starts or ends a token ("lhand", "hip_l"), which is enough when the swapped name
    must also exist. Strict: it starts a token and is followed by an upper-case letter, a
    separator or the end ("LThumb", "Bip01 L Thigh", "hip_l"), which is safe to read alone.
    """
    if name[i] not in _LETTER_SWAP:
        return False
    before = name[i - 1] if i > 0 else ""
    after = name[i + 1] if i + 1 < len(name) else ""
    starts = before == "" or before in _SEPARATORS
    ends = after == "" or after in _SEPARATORS
    if strict:
        return starts and (ends or after.isupper())
    return starts or ends


def _letter_candidates(name: str):
    """Names obtained by swapping one single side letter (prefix, suffix or separated token)."""
    for i, ch in enumerate(name):
        if _is_side_letter(name, i, strict=False):
            yield name[:i] + _LETTER_SWAP[ch] + name[i + 1:]


def mirror_pairs(names: Sequence[str], source: str | None = None) -> np.ndarray:
    """``(J,)`` permutation mapping each joint to its left/right counterpart (itself if none).

    The result is an involution: ``pairs[pairs] == arange(J)``.
    """
    index = {n: i for i, n in enumerate(names)}
    pairs = np.arange(len(names))
    for i, name in enumerate(names):
        other = _word_counterpart(name)
        if other is not None:
            if other not in index:
                raise MotionDataError(
                    f"joint {name!r} has no counterpart {other!r} on the other side; cannot mirror", source)
            pairs[i] = index[other]
            continue
        for cand in _letter_candidates(name):
            if cand in index and cand != name:
                pairs[i] = index[cand]
                break
    if not np.array_equal(pairs[pairs], np.arange(len(names))):
        bad = [names[i] for i in range(len(names)) if pairs[pairs[i]] != i]
        raise MotionDataError(f"inconsistent left/right pairing for joints {bad}", source)
    return pairs


def side_of(name: str) -> str | None:
    """``"left"``, ``"right"`` or ``None`` judged from a joint name alone (word or letter forms)."""
    for a, b in _WORD_SWAPS:
        if a in name:
            return "left"
        if b in name:
            return "right"
    for i, ch in enumerate(name):
        if _is_side_letter(name, i, strict=True):
            return "left" if ch in "Ll" else "right"
    return None


def _strip_side(name: str) -> str:
    for a, b in _WORD_SWAPS:
        name = name.replace(a, "").replace(b, "")
    name = re.sub(r"^(mixamorig:|bip\d*\s*)", "", name, flags=re.IGNORECASE)
    return name.strip(_SEPARATORS)


_HIP_NAMES = ("upleg", "thigh", "hip", "upperleg", "hipjoint")
_SHOULDER_NAMES = ("arm", "uparm", "upperarm", "shoulder", "shldr")


def _find_pair(names: Sequence[str], pairs: np.ndarray, keywords: Sequence[str]) -> tuple[str, str] | None:
    candidates = []  # (rank, left, right)
    for i, j in enumerate(pairs):
        if i == j or side_of(names[i]) != "left":
            continue
        stem = _strip_side(names[i])
        if stem and _is_side_letter(stem, 0, strict=True):
            stem = stem[1:]  # drop a side letter prefix: "LHipJoint" -> "HipJoint"
        stem = stem.strip(_SEPARATORS).lower()
        for rank, kw in enumerate(keywords):
            if stem == kw:
                candidates.append((rank, names[i], names[j]))
    if not candidates:
        return None
    candidates.sort()
    return candidates[0][1], candidates[0][2]


def find_hips_and_shoulders(names: Sequence[str], source: str | None = None
                            ) -> tuple[tuple[str, str], tuple[str, str]]:
    """``((left_hip, right_hip), (left_shoulder, right_shoulder))`` found by name.

    Hips prefer the thigh joint (``UpLeg``, ``Thigh``, ``Hip``); shoulders prefer the upper arm
    (``Arm``, ``UpperArm``, ``Shoulder``), which is what the lateral across-vector needs.
    """
    pairs = mirror_pairs(names, source)
    hips = _find_pair(names, pairs, _HIP_NAMES)
    shoulders = _find_pair(names, pairs, _SHOULDER_NAMES)
    if hips is None or shoulders is None:
        missing = "hip" if hips is None else "shoulder"
        raise MotionDataError(
            f"cannot find the left/right {missing} joints by name among {', '.join(names)}; "
            "pass hips=(left, right) and shoulders=(left, right) explicitly", source)
    return hips, shoulders


_ANKLE_NAMES = ("ankle", "foot")
_TOE_NAMES = ("toebase", "toe", "toe0", "ball", "toes")
_HAND_NAMES = ("hand", "wrist")


def find_feet_and_hands(names: Sequence[str], source: str | None = None) -> dict[str, tuple[str, str]]:
    """``{"ankles": (left, right), "toes": (left, right), "hands": (left, right)}`` found by name.

    Ankles are ``Ankle`` (100STYLE) or ``Foot`` (CMU, Mixamo); toes ``ToeBase`` (CMU, Mixamo) or
    ``Toe`` (100STYLE); hands ``Hand`` (CMU) or ``Wrist`` (100STYLE). Raises
    :class:`MotionDataError` naming what is missing, so the caller can pass joints explicitly.
    """
    pairs = mirror_pairs(names, source)
    found = {"ankles": _find_pair(names, pairs, _ANKLE_NAMES),
             "toes": _find_pair(names, pairs, _TOE_NAMES),
             "hands": _find_pair(names, pairs, _HAND_NAMES)}
    missing = [k for k, v in found.items() if v is None]
    if missing:
        raise MotionDataError(
            f"cannot find the left/right {', '.join(missing)} by name among {', '.join(names)}; "
            "pass the joint names explicitly", source)
    return found
