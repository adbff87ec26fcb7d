"""The training rows of the 2022 style models (Mason, Starke & Komura 2022, section 4.3):
:func:`style_data` turns an LPN :class:`jaxstyle.data.datasets.Dataset` into normalised arrays
(:class:`StyleData`: inputs, outputs, the gating input of the backbone, normalised style clips, and
per style its training / validation / test rows and training clips, clips lying wholly in training
rows), with where the joint positions sit in the outputs (:class:`BonePositions`, for the
bone-length loss; :class:`FootContacts`, for the contact loss), each row's next frame
(:func:`next_rows`, for rollout training) and the arrays as the jitted losses take them
(:func:`device_arrays`, :class:`StaticBones`).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.data.datasets import consecutive_rows
from jaxstyle.data.lpn_features import LPNLayout, bone_parents, end_effector_columns, foot_bones
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.motion import Motion


class FootContacts(NamedTuple):
    """Where the feet sit in the rows, for :func:`jaxstyle.mason2022.loss.contact_loss`: ``feet``
    the LPN bone indices of the ankles and toes, ``side`` each one's foot (0 left, 1 right: the
    order of the outputs' ``foot_contact``); per group ``(start, scale, offset)`` de-normalising
    the inputs' joint positions (``x_position``, to metres), the outputs' joint velocities
    (``y_velocity``, metres per frame) and the outputs' foot contacts (``y_contact``, labels in
    ``[0, 1]``): ``value = row[start:start + n] * scale + offset``."""

    feet: tuple[int, ...]
    side: tuple[int, ...]
    x_position: tuple
    y_velocity: tuple
    y_contact: tuple

    def key(self) -> tuple:
        """The hashable identity of the values (for :class:`StaticBones`)."""
        return (self.feet, self.side) + tuple(
            (g[0], np.asarray(g[1]).tobytes(), np.asarray(g[2]).tobytes())
            for g in (self.x_position, self.y_velocity, self.y_contact))


class BonePositions(NamedTuple):
    """Where the joint positions sit in the outputs and how to de-normalise them to metres:
    ``metres = y[:, start:start + 3 J] * scale + offset``; ``parents (J,)`` of the bones;
    ``contact``: the feet's :class:`FootContacts` (``None``: no contact loss possible)."""

    start: int
    scale: np.ndarray
    offset: np.ndarray
    parents: tuple[int, ...]
    contact: FootContacts | None = None


class StyleData(NamedTuple):
    """Normalised arrays of an LPN dataset for the style models (see :func:`style_data`)."""

    x: np.ndarray
    y: np.ndarray
    gate: np.ndarray
    clips: np.ndarray
    train_rows: tuple[np.ndarray, ...]
    val_rows: tuple[np.ndarray, ...]
    test_rows: tuple[np.ndarray, ...]
    train_clips: tuple[np.ndarray, ...]
    styles: tuple[str, ...]
    bones: BonePositions
    next_row: np.ndarray | None = None
    stats: tuple | None = None


def next_rows(clip_N: np.ndarray, frame_N: np.ndarray) -> np.ndarray:
    """``(N,)``: for each row the row of the next frame of the same clip, -1 where there is none."""
    out = np.full(len(clip_N), -1, np.int64)
    a, b = consecutive_rows(clip_N, frame_N)
    out[a] = b
    return out


def rollout_starts(rows: np.ndarray, next_row: np.ndarray, steps: int) -> np.ndarray:
    """The ``rows`` followed by ``steps`` more frames of their clip that are all among ``rows``
    (the starts of :func:`jaxstyle.mason2022.loss.rollout_loss`'s windows; a window never runs into another split)."""
    rows = np.asarray(rows)
    inside = np.zeros(len(next_row) + 1, bool)
    inside[rows] = True
    cur, ok = rows.copy(), np.ones(len(rows), bool)
    for _ in range(steps):
        cur = next_row[cur]
        ok &= (cur >= 0) & inside[cur]
        cur = np.where(cur >= 0, cur, rows)
    return rows[ok]


def global_phase_rows(dataset) -> np.ndarray:
    """``(N,)`` the global phase of every row of an LPN dataset (the PFNN backbone's gate); an
    error naming the fix when the dataset was built (or cached) without it."""
    phase = np.asarray(getattr(dataset, "global_phase", np.zeros(0)))
    if len(phase) != len(dataset.inputs):
        raise ValueError(f"the dataset has {len(phase)} global phases for {len(dataset.inputs)} rows: build it "
                         "again with jaxstyle.data.datasets.build_lpn_dataset (its cache predates the global phase)")
    return phase


def style_data(dataset, skeleton: Motion, *, backbone: str = "lpn", styles: Sequence[str] | None = None,
               base=None, gate: np.ndarray | None = None) -> StyleData:
    """Arrays for training or testing on ``styles`` (default all) of an LPN dataset.

    ``skeleton``: a clip of the dataset's skeleton (bone parents and units). ``base``: normalise
    with another dataset's statistics (a new style with the base model's, as both papers do).
    The gating input (unless ``gate`` gives one per row) is the 8 local-phase values (``"lpn"``),
    the 12 end-effector velocity inputs (``"mann"``) or the global phase in cycles (``"pfnn"``,
    ``(N, 1)``: the dataset's ``global_phase``, :func:`jaxstyle.global_phase` of each row's frame).
    """
    styles = tuple(dataset.styles if styles is None else styles)
    layout = LPNLayout.of_inputs(dataset.inputs.shape[1])
    if dataset.clips.shape[0] == 0:
        raise ValueError("the dataset has no style clips: build it with jaxstyle.data.datasets.build_lpn_dataset")
    x, y = dataset.normalised(base)
    x_norm, y_norm = (base or dataset).normalisers()
    if gate is None:
        if backbone == "lpn":
            gate = dataset.phases
        elif backbone == "mann":
            gate = x[:, end_effector_columns(skeleton)]
        elif backbone == "pfnn":
            gate = global_phase_rows(dataset)[:, None]
        else:
            raise ValueError(f"unknown backbone {backbone!r}")
    gate = np.asarray(gate, np.float32)
    if len(gate) != len(x):
        raise ValueError(f"gate has {len(gate)} rows, the dataset {len(x)}")
    joints = layout.input_groups
    clips = ((dataset.clips - x_norm.mean[joints["joint_position"].start:])
             / x_norm.std[joints["joint_position"].start:]).astype(np.float32)
    pos = layout.output_groups["joint_position"]
    unit = estimate_units_per_meter(skeleton)
    parents = bone_parents(skeleton)
    if len(parents) != layout.num_bones:
        raise ValueError(f"the skeleton has {len(parents)} LPN bones, the dataset {layout.num_bones}")
    bones = BonePositions(pos.start, (y_norm.std[pos] / unit).astype(np.float32),
                          (y_norm.mean[pos] / unit).astype(np.float32), tuple(int(p) for p in parents),
                          foot_contacts(skeleton, layout, (x_norm, y_norm), unit))
    train_clips = tuple(dataset.clips_of_style(s, "train") for s in styles)
    for s, c in zip(styles, train_clips, strict=True):
        if len(c) == 0:
            raise ValueError(f"style {s!r} has no style clip inside its training rows")
    stats = tuple(np.asarray(a, np.float32) for a in (x_norm.mean, x_norm.std, y_norm.mean, y_norm.std))
    return StyleData(x, y, gate, clips, tuple(dataset.rows_of_style(s, "train") for s in styles),
                     tuple(dataset.rows_of_style(s, "validation") for s in styles),
                     tuple(dataset.rows_of_style(s, "test") for s in styles), train_clips, styles, bones,
                     next_rows(dataset.clip, dataset.frame), stats)


def foot_contacts(skeleton: Motion, layout: LPNLayout, normalisers, units_per_meter: float) -> FootContacts:
    """The :class:`FootContacts` of an LPN layout on ``skeleton`` (:func:`foot_bones`) with the
    (input, output) normalisers ``(x_norm, y_norm)``."""
    feet, side = foot_bones(skeleton)
    x_norm, y_norm = normalisers

    def group(norm, sl, unit=1.0):
        return (sl.start, (norm.std[sl] / unit).astype(np.float32), (norm.mean[sl] / unit).astype(np.float32))

    return FootContacts(feet, side,
                        group(x_norm, layout.input_groups["joint_position"], units_per_meter),
                        group(y_norm, layout.output_groups["joint_velocity"], units_per_meter),
                        group(y_norm, layout.output_groups["foot_contact"]))


class StaticBones:
    """Wraps :class:`BonePositions` so ``jit`` can take it as a static argument (by identity of
    its values)."""

    def __init__(self, bones: BonePositions):
        self.bones = bones
        self._key = (bones.start, bones.parents, bones.scale.tobytes(), bones.offset.tobytes(),
                     None if bones.contact is None else bones.contact.key())

    def __hash__(self):
        return hash(self._key)

    def __eq__(self, other):
        return isinstance(other, StaticBones) and self._key == other._key


def bones_of(b) -> BonePositions:
    """The :class:`BonePositions` of ``b`` (itself, or the ones a :class:`StaticBones` wraps)."""
    return b.bones if isinstance(b, StaticBones) else b


def device_arrays(data: StyleData) -> tuple[jax.Array, ...]:
    """``(x, y, gate, clips)`` of ``data`` on the device (what the losses index by row)."""
    return tuple(jnp.asarray(a) for a in (data.x, data.y, data.gate, data.clips))
