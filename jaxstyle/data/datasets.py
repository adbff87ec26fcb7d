"""Datasets of training rows for both papers, built from folders of BVH files and cached.

A dataset is built from a list of :class:`jaxstyle.data.clips.ClipSpec` (file, style, frame
range, mirrored or not), which the ``specs_*`` functions of :mod:`jaxstyle.data.clips` make for the
layouts in use.

:func:`build_pfnn_dataset` and :func:`build_lpn_dataset` encode every clip (2018 and 2022 layouts)
and keep, per row, its style, clip, frame and split (contiguous blocks per clip; a clip and its
mirror share them), with normalisation statistics over the training rows of all styles. Results
are cached under ``cache_dir`` in a file
named by a hash of the input files' contents, the specs and the settings: a changed file or
setting builds anew, an unchanged one loads in well under a second.

Guards (see ``docs/bad_input.md``): every clip of a dataset must have the first clip's skeleton
(same joints, same order), every feature row must be finite and below :data:`FEATURE_LIMIT`
(the error names the file and the frame), a clip too short for the trajectory window is an error
or, with ``skip_short``, a warning naming it, its length and the minimum, and a style left with no
clip is an error. A cache file holding non-finite values is not used.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import warnings
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from jaxstyle.data.batching import SPLITS, contiguous_split
from jaxstyle.data.clips import ClipSpec, with_joint_map
from jaxstyle.data.lpn_features import LPNLayout, encode_lpn
from jaxstyle.data.normalise import Normaliser, fit_normaliser
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES, PAST_SAMPLES, PFNNLayout, encode_pfnn, sample_step, valid_frames
from jaxstyle.errors import MotionDataError
from jaxstyle.labels.phase import global_phase, read_phase_labels
from jaxstyle.motion import Motion, transform
from jaxstyle.motion.bvh import read_bvh
from jaxstyle.motion.skeleton import JointMap

CACHE_VERSION = 4
"""Part of every cache key; raised when the rows of the same files and settings change. 4: the
labels' contact rule scales with the skeleton and frame rate, and landings of both feet are one
footstep (jaxstyle.labels.contacts, jaxstyle.labels.phase), which changes the global phase and, off
100STYLE, the local phases."""
FEATURE_LIMIT = 1e6
"""The largest magnitude a feature value may have. Features are positions (in the file's units,
centimetres for 100STYLE: at most a few thousand over the 11 s trajectory window), velocities,
rotations and phases; a value beyond this comes from an absurd input value (a root at 1e300
passes as a finite number and overflows float32) and is refused."""

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class Dataset:
    """Rows of one layout, float32. ``inputs (N, Din)``, ``outputs (N, Dout)``, ``phases (N, P)`` (the
    global phase for the PFNN, the 8 local-phase values for the LPN); per row ``style`` (index
    into ``styles``), ``clip`` (index into ``specs``) and ``frame``; ``clips (C, 240, 300)`` with
    ``clip_style (C,)``, ``clip_source (C,)`` (index into ``specs``) and ``clip_start (C,)`` (first
    frame) for the LPN (empty for the PFNN); ``split (N,)`` 0/1/2 for train,
    validation, test (-1 in a gap); the input/output statistics of :meth:`normalisers`; and for
    the LPN ``global_phase (N,)``, the PFNN phase of each row (:func:`jaxstyle.global_phase`), the
    gate of Table 2's PFNN-backbone models (empty for the PFNN layout, whose ``phases`` hold it)."""

    styles: tuple[str, ...]
    specs: tuple[ClipSpec, ...]
    inputs: np.ndarray
    outputs: np.ndarray
    phases: np.ndarray
    style: np.ndarray
    clip: np.ndarray
    frame: np.ndarray
    clips: np.ndarray
    clip_style: np.ndarray
    clip_source: np.ndarray
    clip_start: np.ndarray
    split: np.ndarray
    input_mean: np.ndarray
    input_std: np.ndarray
    output_mean: np.ndarray
    output_std: np.ndarray
    global_phase: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.float32))

    def rows_of_style(self, name: str, split: str | None = None) -> np.ndarray:
        """Row indices of a style, optionally of one split (``"train"``, ``"validation"``, ``"test"``)."""
        if name not in self.styles:
            raise KeyError(f"unknown style {name!r}; the dataset has {', '.join(self.styles)}")
        keep = self.style == self.styles.index(name)
        if split is not None:
            keep &= self.split == SPLITS.index(split)
        return np.flatnonzero(keep)

    def clips_of_style(self, name: str, split: str | None = None) -> np.ndarray:
        """Style-clip indices of a style; with ``split``, only clips whose frames all lie in rows of
        that split (a clip overlapping validation or test rows is not a training clip)."""
        if name not in self.styles:
            raise KeyError(f"unknown style {name!r}; the dataset has {', '.join(self.styles)}")
        found = np.flatnonzero(self.clip_style == self.styles.index(name))
        if split is None:
            return found
        want = SPLITS.index(split)
        frames = self.clips.shape[1]
        keep = []
        for c in found:
            rows = (self.clip == self.clip_source[c]) & (self.frame >= self.clip_start[c]) & (
                self.frame < self.clip_start[c] + frames)
            if rows.any() and (self.split[rows] == want).all():
                keep.append(c)
        return np.asarray(keep, dtype=np.int64)

    def mirror_rows(self) -> np.ndarray:
        """``(N,)`` the row of each row's mirrored twin (same frame of the clip's mirrored copy),
        or -1 where the clip has no mirrored copy; for the half-mirrored batches of
        :func:`jaxstyle.data.batching.balanced_batches` (``mirror_of=``)."""
        out = np.full(len(self.clip), -1, dtype=np.int64)
        where = {(s.path, s.start, s.stop, s.mirror): i for i, s in enumerate(self.specs)}
        for i, s in enumerate(self.specs):
            j = where.get((s.path, s.start, s.stop, not s.mirror))
            if j is None:
                continue
            rows_i, rows_j = np.flatnonzero(self.clip == i), np.flatnonzero(self.clip == j)
            # both copies have the same frames, in the same order
            out[rows_i] = rows_j
        return out

    def normalisers(self) -> tuple[Normaliser, Normaliser]:
        """Input and output statistics over the training rows of all styles (see
        :mod:`jaxstyle.data.normalise`)."""
        return Normaliser(self.input_mean, self.input_std), Normaliser(self.output_mean, self.output_std)

    def normalised(self, base: "Dataset | None" = None) -> tuple[np.ndarray, np.ndarray]:
        """``(inputs, outputs)`` normalised with this dataset's statistics, or with ``base``'s.

        A few-shot style is a small dataset of its own; normalise it with the base dataset's
        statistics (``few_shot.normalised(base)``), as both papers do, never with its own.
        """
        x_norm, y_norm = (base or self).normalisers()
        return x_norm.apply(self.inputs).astype(np.float32), y_norm.apply(self.outputs).astype(np.float32)


FORWARD_GAITS = ("FW", "FR")
"""The gaits a character starts from and takes its own speed from, in order of preference: a
forward walk, else a forward run (the paths move forward)."""


def consecutive_rows(clip_N: np.ndarray, frame_N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(a, b)``: the indices of every pair of rows where row ``b[k]`` is the frame after row
    ``a[k]`` in the same clip (rows in any order; each frame of a clip once)."""
    clip, frame = np.asarray(clip_N), np.asarray(frame_N)
    order = np.lexsort((frame, clip))
    follows = (clip[order][1:] == clip[order][:-1]) & (frame[order][1:] == frame[order][:-1] + 1)
    return order[:-1][follows], order[1:][follows]


def style_rows(dataset: Dataset, style: str, gaits: Sequence[str] = FORWARD_GAITS) -> np.ndarray:
    """Training rows of ``style``, only those of its clips of the first of ``gaits`` it has (all its
    rows when it has none of them): where a driven character of the style starts, and what its own
    speed and capture are read from."""
    rows = dataset.rows_of_style(style, "train")
    if len(rows) == 0:
        rows = dataset.rows_of_style(style)
    clip_gaits = np.array([dataset.specs[c].gait for c in dataset.clip[rows]])
    for gait in gaits:
        if (clip_gaits == gait).any():
            return rows[clip_gaits == gait]
    return rows


def _load(spec: ClipSpec, fps: float | None) -> tuple[Motion, float]:
    """The motion of a spec (see :func:`load_clip`) and the file's own frame rate."""
    motion = read_bvh(spec.path)
    if spec.joint_map is not None:
        spec.joint_map.check(motion.names, spec.path)
        motion = motion.replace(joint_map=spec.joint_map)
    source_fps = motion.fps
    stop = motion.num_frames if spec.stop is None else min(spec.stop, motion.num_frames)
    if not 0 <= spec.start < stop:
        raise MotionDataError(f"frame range [{spec.start}, {spec.stop}) is empty for a clip of "
                              f"{motion.num_frames} frames", spec.path)
    motion = motion.frames(spec.start, stop)
    _check_motion(spec, motion)
    if fps is not None and motion.fps != fps:
        motion = transform.resample(motion, fps)
    return (transform.mirror(motion) if spec.mirror else motion), source_fps


def _out_of_range(flat_NxD: np.ndarray) -> np.ndarray:
    """``(N, D)`` True where a value is not finite or beyond :data:`FEATURE_LIMIT`."""
    with np.errstate(invalid="ignore"):
        return ~(np.isfinite(flat_NxD) & (np.abs(flat_NxD) <= FEATURE_LIMIT))


def _check_motion(spec: ClipSpec, motion: Motion) -> None:
    """Refuse a clip whose joint positions or rotations are not finite or beyond
    :data:`FEATURE_LIMIT` (a root at 1e300 is a finite number the reader accepts), naming the
    file and the first such frame."""
    for name, arr in (("joint positions", motion.local_positions), ("joint rotations", motion.rotations)):
        flat = np.asarray(arr).reshape(len(arr), -1)
        out = _out_of_range(flat)
        bad = out.any(axis=1)
        if bad.any():
            f = int(np.argmax(bad))
            joint = int(np.argmax(out[f])) // (flat.shape[1] // len(motion.names))
            value = flat[f][out[f]][0]
            what = "not finite" if not np.isfinite(value) else f"beyond {FEATURE_LIMIT:g}"
            raise MotionDataError(f"frame {spec.start + f} (0-based) has {name} of {motion.names[joint]!r} {what}"
                                  f" ({value:g}; {int(bad.sum())} such frames); fix or cut those frames", spec.path)


def load_clip(spec: ClipSpec, fps: float | None = None) -> Motion:
    """The motion of a spec: cut, resampled to ``fps`` if given, mirrored if asked."""
    return _load(spec, fps)[0]


def _cache_key(kind: str, specs: Sequence[ClipSpec], settings: dict) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({"kind": kind, "version": CACHE_VERSION, "settings": settings,
                         "specs": [s.to_json() for s in specs]}, sort_keys=True, allow_nan=False).encode())
    for path in sorted({s.path for s in specs} | {str(Path(s.path).with_suffix(".phase")) for s in specs
                                                  if s.phase_labels}):
        h.update(path.encode())
        h.update(Path(path).read_bytes())
    return h.hexdigest()[:24]


def _cached(kind: str, specs: Sequence[ClipSpec], settings: dict, cache_dir, build: Callable[[], Dataset]) -> Dataset:
    if cache_dir is None:
        return build()
    path = Path(cache_dir) / f"{kind}-{_cache_key(kind, specs, settings)}.npz"
    if path.is_file():
        with np.load(path) as data:
            meta = json.loads(str(data["meta"]))
            arrays = {k: data[k] for k in data.files if k != "meta"}
        if all(np.isfinite(v).all() for v in arrays.values() if np.issubdtype(v.dtype, np.inexact)):
            return Dataset(styles=tuple(meta["styles"]), specs=tuple(ClipSpec.from_json(s) for s in meta["specs"]),
                           **arrays)
        log.warning("%s holds NaN or infinity (cached by an older jaxstyle); building it again", path)
    dataset = build()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    meta = json.dumps({"styles": dataset.styles, "specs": [s.to_json() for s in dataset.specs]},
                      allow_nan=False)
    arrays = {f.name: getattr(dataset, f.name) for f in dataclasses.fields(dataset)
              if f.name not in ("styles", "specs")}
    with open(tmp, "wb") as f:
        np.savez(f, meta=np.array(meta), **arrays)
    os.replace(tmp, path)  # atomic: an interrupted build leaves no half-written cache file
    return dataset


def _split_seed(spec: ClipSpec, seed: int) -> int:
    """Same for a clip and its mirrored twin, so both land in the same split blocks."""
    key = f"{Path(spec.path).name}:{spec.start}:{spec.stop}:{seed}".encode()
    return int.from_bytes(hashlib.sha256(key).digest()[:4], "little")


def _assemble(specs, per_clip, layout_groups, with_clips: bool, split: SplitSettings) -> Dataset:
    styles = tuple(dict.fromkeys(s.style for s in specs))
    xs, ys, ps, st, cl, fr, sp, clips, clip_style, clip_source, clip_start = ([] for _ in range(11))
    for i, (spec, (x, y, p, t, c, c_start)) in enumerate(zip(specs, per_clip, strict=True)):
        xs.append(x), ys.append(y), ps.append(p), fr.append(t)
        st.append(np.full(len(t), styles.index(spec.style))), cl.append(np.full(len(t), i))
        blocks = contiguous_split(len(t), split.fractions, gap=split.gap, seed=_split_seed(spec, split.seed))
        rows = np.full(len(t), -1, np.int8)  # -1: dropped in a gap
        for k, name in enumerate(SPLITS):
            rows[blocks[name]] = k
        sp.append(rows)
        if with_clips:
            clips.append(c), clip_style.append(np.full(len(c), styles.index(spec.style)))
            clip_source.append(np.full(len(c), i)), clip_start.append(c_start)
    x, y, splits = np.concatenate(xs), np.concatenate(ys), np.concatenate(sp)
    in_groups, out_groups = layout_groups(x.shape[1])
    train = splits == 0
    x_norm, y_norm = fit_normaliser([x[train]], in_groups), fit_normaliser([y[train]], out_groups)
    empty = np.zeros((0, 240, x.shape[1] - 48 if with_clips else 0))
    f32 = np.float32  # training precision; halves the cache

    def ints(parts):
        return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)

    return Dataset(styles, tuple(specs), x.astype(f32), y.astype(f32), np.concatenate(ps).astype(f32),
                   np.concatenate(st), np.concatenate(cl), np.concatenate(fr),
                   (np.concatenate(clips) if clips else empty).astype(f32),
                   ints(clip_style), ints(clip_source), ints(clip_start), splits,
                   x_norm.mean, x_norm.std, y_norm.mean, y_norm.std)


@dataclasses.dataclass(frozen=True)
class SplitSettings:
    """Per-clip contiguous blocks (see :func:`jaxstyle.data.batching.contiguous_split`)."""

    fractions: tuple[float, float, float] = (0.8, 0.1, 0.1)
    gap: int = 0
    seed: int = 0


def _pfnn_groups(input_size: int):
    layout = PFNNLayout((input_size - 48) // 6)
    return layout.input_groups, layout.output_groups


def _lpn_groups(input_size: int):
    layout = LPNLayout.of_inputs(input_size)
    out = dict(layout.output_groups)
    for name in ("local_phase", "local_phase_update", "foot_contact"):
        out.pop(name)  # per-dimension statistics for these few values
    return layout.input_groups, out


def _progress(items, desc: str, progress: bool):
    if not progress:
        return items
    from tqdm.auto import tqdm

    return tqdm(items, desc=desc, unit="clip")


def min_frames(fps: float) -> int:
    """The fewest frames a clip at ``fps`` needs to cover the trajectory window (6 s before a
    frame, 5 s after it): shorter clips give no training row."""
    return PAST_SAMPLES * sample_step(fps) + (FUTURE_SAMPLES - 1) * sample_step(fps) + 2


def _long_enough(motion: Motion, spec: ClipSpec, skip_short: bool) -> bool:
    """Whether a loaded clip covers the trajectory window; if not, a warning (``skip_short``) or
    an error naming the file, its length and the minimum."""
    if len(valid_frames(motion.num_frames, motion.fps)) > 0:
        return True
    what = (f"clip of style {spec.style!r} has {motion.num_frames} frames at {motion.fps:g} fps, shorter than "
            f"the trajectory window (at least {min_frames(motion.fps)} frames, "
            f"{min_frames(motion.fps) / motion.fps:.1f} s)")
    if skip_short:
        message = f"{spec.path}: {what}; skipped"
        warnings.warn(message, stacklevel=4)
        log.warning(message)  # seen even where the caller silences warnings (the pipelines do)
        return False
    raise MotionDataError(f"{what} (pass skip_short=True to leave such clips out)", spec.path)


def _check_skeleton(first: tuple[ClipSpec, tuple[str, ...]], spec: ClipSpec, names: tuple[str, ...]) -> None:
    """Refuse a clip whose skeleton differs from the first clip's (naming both files)."""
    first_spec, first_names = first
    if names == first_names:
        return
    if len(names) != len(first_names):
        detail = f"{len(names)} joints, but {first_spec.path} has {len(first_names)}"
    else:
        i = next(i for i, (a, b) in enumerate(zip(names, first_names, strict=True)) if a != b)
        detail = (f"{len(names)} joints like {first_spec.path}, but joint {i} is {names[i]!r} there "
                  f"{first_names[i]!r}")
    raise MotionDataError(f"skeleton of style {spec.style!r} has {detail} (style {first_spec.style!r}); a dataset "
                          "needs one skeleton: keep each skeleton's clips in its own data folder", spec.path)


def _check_rows(spec: ClipSpec, motion_fps: float, source_fps: float, arrays, frames_of) -> None:
    """Refuse non-finite or absurd (beyond :data:`FEATURE_LIMIT`) feature values, naming the file
    and the first bad frame (of the file: the clip's start added, at the file's rate)."""
    for name, arr in arrays:
        arr = np.asarray(arr)
        if arr.size == 0:
            continue
        flat = arr.reshape(len(arr), -1)
        out = _out_of_range(flat)
        bad_rows = out.any(axis=1)
        if not bad_rows.any():
            continue
        r = int(np.argmax(bad_rows))
        frame = int(frames_of(name, r))
        file_frame = spec.start + int(round(frame * source_fps / motion_fps))
        values = flat[r][out[r]]
        raise MotionDataError(
            f"the row of frame {file_frame} (style {spec.style!r}{', mirrored' if spec.mirror else ''}) gives {name} "
            f"{'that are not finite' if not np.isfinite(values).all() else 'beyond ' + format(FEATURE_LIMIT, 'g')} "
            f"(e.g. {values[0]:g}; {int(bad_rows.sum())} of {len(flat)} rows): the file holds an absurd or "
            "non-finite value near that frame", spec.path)


def _encode_all(specs, fps, skip_short, progress, desc, encode):
    """``(kept specs, per-clip arrays)``: each clip read once, short ones skipped or refused, one
    skeleton, finite rows; a style left with no clip is an error."""
    kept, per_clip, first, short = [], [], None, {}
    for spec in _progress(specs, desc, progress):
        motion, source_fps = _load(spec, fps)
        names = tuple(motion.names)
        if first is None:
            first = (spec, names)
        else:
            _check_skeleton(first, spec, names)
        if not _long_enough(motion, spec, skip_short):
            short.setdefault(spec.style, []).append(f"{spec.path} ({motion.num_frames} frames, needs "
                                                    f"{min_frames(motion.fps)})")
            continue
        arrays = encode(spec, motion, source_fps)
        x, y, p, t, c, c_start = arrays

        def frames_of(name, r, t=t, c_start=c_start):
            return c_start[r] if name == "style clips" else t[r]

        _check_rows(spec, motion.fps, source_fps,
                    (("inputs", x), ("outputs", y), ("phases", p), ("style clips", c if c is not None else [])),
                    frames_of)
        kept.append(spec)
        per_clip.append(arrays)
    lost = [style for style in dict.fromkeys(s.style for s in specs) if style not in {s.style for s in kept}]
    if lost:
        listing = "; ".join(f"style {style!r}: {', '.join(dict.fromkeys(short.get(style, [])))}" for style in lost)
        raise MotionDataError(f"{len(lost)} style(s) have no clip long enough for the trajectory window: {listing}; "
                              "give them longer clips or leave them out")
    return kept, per_clip


def build_pfnn_dataset(specs: Sequence[ClipSpec], *, fps: float = 60.0, cache_dir: str | os.PathLike | None = None,
                       split: SplitSettings = SplitSettings(), skip_short: bool = False,
                       progress: bool = False, joint_map: JointMap | None = None) -> Dataset:
    """2018 PFNN rows of all clips at ``fps`` (the paper: 60). The phase is the ``.phase`` labels
    (resampled by nearest frame) when the spec says so, else :func:`jaxstyle.global_phase`.
    A clip shorter than the trajectory window is an error naming the file, or is skipped with a
    warning when ``skip_short``. ``joint_map`` goes on every clip that has none (see
    :class:`ClipSpec`)."""
    if not specs:
        raise ValueError("no clips")
    specs = with_joint_map(specs, joint_map)

    def encode(spec, motion, source_fps):
        if spec.phase_labels:
            labels, _ = read_phase_labels(spec.path)
            idx = np.round((spec.start + np.arange(motion.num_frames)) * source_fps / fps).astype(int)
            phase = labels[np.minimum(idx, len(labels) - 1)]
        else:
            phase = global_phase(motion)
        x, y, t = encode_pfnn(motion, phase)
        return x, y, phase[t][:, None], t, None, None

    def build():
        kept, per_clip = _encode_all(specs, fps, skip_short, progress, "PFNN features", encode)
        return _assemble(kept, per_clip, _pfnn_groups, with_clips=False, split=split)

    settings = {"fps": fps, "skip_short": skip_short, "split": dataclasses.asdict(split)}
    return _cached("pfnn", specs, settings, cache_dir, build)


def build_lpn_dataset(specs: Sequence[ClipSpec], *, cache_dir: str | os.PathLike | None = None,
                      split: SplitSettings = SplitSettings(), skip_short: bool = False,
                      progress: bool = False, joint_map: JointMap | None = None) -> Dataset:
    """2022 LPN rows and style clips of all clips (at the files' rate; 100STYLE is 60 fps).
    Short clips and ``joint_map`` are handled as in :func:`build_pfnn_dataset`."""
    if not specs:
        raise ValueError("no clips")
    specs = with_joint_map(specs, joint_map)

    def encode(spec, motion, source_fps):
        f = encode_lpn(motion)  # the global phase rides as a 9th phase column until _assemble is done
        return f.inputs, f.outputs, np.column_stack([f.phases, f.global_phase]), f.frames, f.clips, f.clip_starts

    def build():
        kept, per_clip = _encode_all(specs, None, skip_short, progress, "LPN features", encode)
        d = _assemble(kept, per_clip, _lpn_groups, with_clips=True, split=split)
        return dataclasses.replace(d, phases=np.ascontiguousarray(d.phases[:, :-1]),
                                   global_phase=np.ascontiguousarray(d.phases[:, -1]))

    settings = {"skip_short": skip_short, "split": dataclasses.asdict(split), "global_phase": True}
    return _cached("lpn", specs, settings, cache_dir, build)
