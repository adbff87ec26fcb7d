"""Joint naming: left/right pairing for mirroring, and finding hips and shoulders by name.

Pairing understands the namings of the data both papers use and their common relatives:

* whole words ``Left``/``Right`` anywhere (100STYLE ``LeftHip``, CMU ``LeftUpLeg``, Mixamo
  ``mixamorig:LeftArm``; also ``left``/``right`` and ``LEFT``/``RIGHT``);
* a single side letter as prefix, suffix or separate token, kept only when the other side's
  name exists: CMU ``LHipJoint``/``RHipJoint`` and ``LThumb``, the 3dsMax-friendly CMU
  ``lhand``/``rhand`` and ``LFingers``, Daz ``lShldr``, ``Bip01 L Thigh``, ``hip_l``, ``Hand.R``.

Names with no side map to themselves (spine, head). A name with ``Left``/``Right`` whose
counterpart is missing is an error, since mirroring such a skeleton cannot be right.

Skeletons whose joints the finders cannot place take a :class:`JointMap` (``--joint-map FILE`` on
the command line, ``joint_map=`` in the dataset builders): a role -> joint table that overrides
the search by name for the roles it gives and adds its left/right pairs to :func:`mirror_pairs`.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import tomllib
from pathlib import Path
from typing import Mapping, Sequence

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


def mirror_pairs(names: Sequence[str], source: str | None = None, joint_map: "JointMap | None" = None) -> np.ndarray:
    """``(J,)`` permutation mapping each joint to its left/right counterpart (itself if none).

    The result is an involution: ``pairs[pairs] == arange(J)``. The (left, right) joints of
    ``joint_map`` pair with each other whatever their names.
    """
    index = {n: i for i, n in enumerate(names)}
    pairs = np.arange(len(names))
    mapped = {}
    if joint_map is not None:
        joint_map.check(names, source)
        for _, left, right in joint_map.roles:
            mapped[left], mapped[right] = right, left
    for i, name in enumerate(names):
        if name in mapped:
            pairs[i] = index[mapped[name]]
            continue
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


def _find_roles(names: Sequence[str], source: str | None, joint_map: "JointMap | None",
                keywords: Mapping[str, Sequence[str]]) -> dict[str, tuple[str, str]]:
    """``{role: (left, right)}`` from ``joint_map`` where it gives the role, else by name; a role
    found neither way is an error naming the roles and the ``--joint-map`` flag."""
    if joint_map is not None:
        joint_map.check(names, source)
    found, pairs = {}, None
    for role, kws in keywords.items():
        given = joint_map.get(role) if joint_map is not None else None
        if given is None:
            pairs = mirror_pairs(names, source, joint_map) if pairs is None else pairs
            given = _find_pair(names, pairs, kws)
        found[role] = given
    missing = [k for k, v in found.items() if v is None]
    if missing:
        raise MotionDataError(
            f"cannot find the left/right {', '.join(missing)} by name among {', '.join(names)}; pass the joint names "
            f"explicitly: a joint map (--joint-map FILE, or joint_map= in the dataset builders) with "
            + ", ".join(f"{m} = [\"<left>\", \"<right>\"]" for m in missing)
            + (f" (the map {joint_map.source} gives {', '.join(r for r, _, _ in joint_map.roles) or 'no role'})"
               if joint_map is not None else ""), source)
    return found


def find_hips_and_shoulders(names: Sequence[str], source: str | None = None, joint_map: "JointMap | None" = None
                            ) -> tuple[tuple[str, str], tuple[str, str]]:
    """``((left_hip, right_hip), (left_shoulder, right_shoulder))`` from ``joint_map`` or by name.

    Hips prefer the thigh joint (``UpLeg``, ``Thigh``, ``Hip``); shoulders prefer the upper arm
    (``Arm``, ``UpperArm``, ``Shoulder``), which is what the lateral across-vector needs.
    """
    found = _find_roles(names, source, joint_map, {"hips": _HIP_NAMES, "shoulders": _SHOULDER_NAMES})
    return found["hips"], found["shoulders"]


_ANKLE_NAMES = ("ankle", "foot")
_TOE_NAMES = ("toebase", "toe", "toe0", "ball", "toes")
_HAND_NAMES = ("hand", "wrist")


def find_feet_and_hands(names: Sequence[str], source: str | None = None, joint_map: "JointMap | None" = None
                        ) -> dict[str, tuple[str, str]]:
    """``{"ankles": (left, right), "toes": (left, right), "hands": (left, right)}`` from
    ``joint_map`` or by name.

    Ankles are ``Ankle`` (100STYLE) or ``Foot`` (CMU, Mixamo); toes ``ToeBase`` (CMU, Mixamo) or
    ``Toe`` (100STYLE); hands ``Hand`` (CMU) or ``Wrist`` (100STYLE). Raises
    :class:`MotionDataError` naming what is missing and the ``--joint-map`` flag that supplies it.
    """
    return _find_roles(names, source, joint_map, {"ankles": _ANKLE_NAMES, "toes": _TOE_NAMES, "hands": _HAND_NAMES})


# --- joint maps ---------------------------------------------------------------------------------

ROLES = ("hips", "shoulders", "ankles", "toes", "hands")
"""The roles a :class:`JointMap` can give, each a (left, right) pair of joints: the thighs and
upper arms (facing direction), the ankles and toes (contacts, phases) and the hands (LPN)."""
_ROLE_ALIASES = {"hip": "hips", "shoulder": "shoulders", "ankle": "ankles", "foot": "ankles", "feet": "ankles",
                 "toe": "toes", "hand": "hands", "wrist": "hands", "wrists": "hands"}


@dataclasses.dataclass(frozen=True)
class JointMap:
    """Role -> (left joint, right joint) for skeletons whose joints are not found by name.

    ``roles`` holds ``(role, left, right)`` sorted by role (roles of :data:`ROLES`); ``source``
    is the file it was read from, named in errors. Read one with :func:`read_joint_map` or build
    it with :meth:`from_mapping`; it is hashable and turns into JSON with :meth:`to_json`.
    """

    roles: tuple[tuple[str, str, str], ...]
    source: str | None = None

    @classmethod
    def from_mapping(cls, mapping: Mapping, source: str | os.PathLike | None = None) -> "JointMap":
        """From ``{role: [left, right]}`` or ``{"left_<role>": joint, "right_<role>": joint}``
        (roles as in :data:`ROLES`, singular forms and ``feet`` for the ankles accepted), mixed
        freely. An unknown key, a value that is not a joint name or a pair of them, or a role
        with only one side is an error naming ``source`` and the key."""
        where = None if source is None else os.fspath(source)
        if not isinstance(mapping, Mapping):
            raise MotionDataError(f"a joint map is a table of role = [left, right], got {type(mapping).__name__}",
                                  where)
        sides: dict[str, dict[str, str]] = {}
        for key, value in mapping.items():
            side, role = None, str(key).strip().lower()
            for prefix in ("left_", "right_"):
                if role.startswith(prefix):
                    side, role = prefix[:-1], role[len(prefix):]
            role = _ROLE_ALIASES.get(role, role)
            if role not in ROLES:
                known = ", ".join(ROLES)
                raise MotionDataError(f"key {key!r}: unknown role; the roles are {known} (each [left, right]), "
                                      "or left_<role> / right_<role> with one joint name", where)
            if side is None:
                ok = (isinstance(value, (list, tuple)) and len(value) == 2
                      and all(isinstance(v, str) and v for v in value))
                if not ok:
                    raise MotionDataError(f"key {key!r}: expected [left, right] joint names, got {value!r}", where)
                given = {"left": value[0], "right": value[1]}
            else:
                if not (isinstance(value, str) and value):
                    raise MotionDataError(f"key {key!r}: expected a joint name, got {value!r}", where)
                given = {side: value}
            for s, joint in given.items():
                if s in sides.setdefault(role, {}):
                    raise MotionDataError(f"key {key!r}: the {s} {role} is given twice", where)
                sides[role][s] = joint
        for role, got in sides.items():
            if len(got) != 2:
                lacking = "right" if "left" in got else "left"
                raise MotionDataError(f"role {role!r}: the {lacking} joint is missing (give {role} = [left, right])",
                                      where)
        return cls(tuple(sorted((r, got["left"], got["right"]) for r, got in sides.items())), where)

    @classmethod
    def from_json(cls, d: Mapping | None) -> "JointMap | None":
        """Inverse of :meth:`to_json` (``None`` stays ``None``)."""
        if d is None:
            return None
        return cls(tuple(tuple(r) for r in d["roles"]), d.get("source"))

    def to_json(self) -> dict:
        return {"roles": [list(r) for r in self.roles], "source": self.source}

    def get(self, role: str) -> tuple[str, str] | None:
        """``(left, right)`` joints of ``role``, or ``None`` when the map does not give it."""
        for r, left, right in self.roles:
            if r == role:
                return left, right
        return None

    def check(self, names: Sequence[str], clip: str | None = None) -> None:
        """Refuse a map naming a joint that the skeleton ``names`` (of the file ``clip``) lacks, and
        one that gives a joint two roles or pairs a joint with itself."""
        have = set(names)
        seen: dict[str, str] = {}
        for role, left, right in self.roles:
            for side, joint in (("left", left), ("right", right)):
                if joint not in have:
                    of = f" of {clip}" if clip else ""
                    raise MotionDataError(f"key {role!r}: {side} joint {joint!r} is not in the skeleton{of}, whose "
                                          f"joints are {', '.join(names)}", self.source)
                if joint in seen:
                    raise MotionDataError(f"key {role!r}: joint {joint!r} also has the role {seen[joint]!r}",
                                          self.source)
                seen[joint] = f"{side} {role}"


def read_joint_map(path: str | os.PathLike) -> JointMap:
    """A :class:`JointMap` from a TOML or JSON file (JSON when it ends in ``.json``, else TOML)::

        # joints.toml
        ankles = ["L_Foot", "R_Foot"]
        toes = ["L_Toes", "R_Toes"]
        left_hand = "L_Hand"
        right_hand = "R_Hand"

    Errors (no such file, a syntax error, an unknown role) name the file and, where there is one,
    the key."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        raise MotionDataError(f"cannot read the joint map: {reason}", path) from None
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (ValueError, tomllib.TOMLDecodeError) as e:
        kind = "JSON" if path.suffix.lower() == ".json" else "TOML"
        raise MotionDataError(f"not valid {kind}: {e}", path) from None
    return JointMap.from_mapping(data, path)
