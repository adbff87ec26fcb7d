"""Local motion phases of the hands and feet (Mason, Starke & Komura 2022, section 4.1).

Pipeline, per end-effector bone ``b`` of a clip (one style x gait take):

1. **Source function** ``G_b(t)``:

   * contact-based (section 4.1.2, feet): the 0/1 contact step function of
     :func:`jaxstyle.labels.contacts.foot_contacts` (a foot touches when its ankle or toe does);
   * contact-free (section 4.1.3, hands; feet of hopping or one-legged styles): the bone's
     position in the character's ground frame, centred on its clip mean and projected on its
     first principal component, the component directed so it points forward (+Z of the character).

2. **Normalisation** (section 4.1.4): z-score in a centred 1 s window; windows without variation
   give 0.
3. **Smoothing**: 2nd-order Butterworth low-pass at 4 Hz applied forward and backward (zero phase).
4. **Fit**: ``A sin(2 pi (F t - S)) + B`` over a 0.5 s window around every frame (31 frames at
   60 fps), ``F`` in 0.25-4 Hz, vectorised in JAX (:mod:`jaxstyle.labels.sinusoid`); phase ``F t - S``.
   jaxstyle bounds ``A <= 2`` (``MAX_AMPLITUDE``; the paper gives no bound, see the comment there).
5. **Feature** (Eq. 1): ``p = |v_w| A (sin 2 pi phase, cos 2 pi phase)``, with ``|v_w|`` the
   bone's mean speed (m/s) in the character frame over a centred 1 s window.

A clip without movement gets zero sources, amplitude 0, phase 0 and zero features (never NaN).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
from scipy import ndimage, signal

from jaxstyle.errors import MotionDataError
from jaxstyle.labels import contacts as contacts_lib
from jaxstyle.labels.sinusoid import SinusoidConfig, SinusoidFit, fit_sinusoids, window_frames
from jaxstyle.motion import Motion, kinematics, skeleton
from jaxstyle.motion.character_frame import character_frames, to_local

NORMALISE_SECONDS = 1.0
VELOCITY_SECONDS = 1.0
BUTTER_ORDER = 2
BUTTER_CUTOFF_HZ = 4.0
SOURCES = ("contact", "free")
# Amplitude bound of the fit, in units of the normalised source. Not in the paper: without it a
# 0.5 s window that sees only a trough or a crest is fitted best by a huge, slow sinusoid far off
# centre (A of 10-30), which stalls the phase and makes the Eq. 1 features spike (99th percentile
# 20-30x the median on 100STYLE clips, 2-3x with the bound; see the README). A z-scored sinusoid
# has A = sqrt(2) and a z-scored contact step function A = 1.1-1.3, so 2 only removes the
# degenerate fits.
MAX_AMPLITUDE = 2.0


def principal_direction(local_TxBx3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(B, 3)`` and first principal component ``(B, 3)`` of each bone's local positions,
    directed to point forward (+Z); a component with no forward part points up, then right."""
    x = np.asarray(local_TxBx3, dtype=np.float64)
    mean = x.mean(axis=0)
    centred = x - mean
    cov = np.einsum("tbi,tbj->bij", centred, centred) / max(len(x), 1)
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues
    pc = vecs[..., -1]  # (B, 3)
    # Direct it (section 4.1.3): forward first, then up, then right, for a tie-free sign.
    for axis in (2, 1, 0):
        key = pc[:, axis]
        decided = np.abs(key) > 1e-9
        pc = np.where((decided & (key < 0))[:, None], -pc, pc)
        if decided.all():
            break
    return mean, pc


def contact_free_source(local_TxBx3: np.ndarray) -> np.ndarray:
    """``(T, B)`` projection of each bone's centred local position on its directed first PC."""
    mean, pc = principal_direction(local_TxBx3)
    return np.einsum("tbc,bc->tb", np.asarray(local_TxBx3) - mean, pc)


def window_normalise(source_TxB: np.ndarray, fps: float, seconds: float = NORMALISE_SECONDS,
                     eps: float = 1e-8) -> np.ndarray:
    """z-score of each frame within a centred window of ``seconds`` (edges use the nearest value).

    Where the window's standard deviation is below ``eps`` (no variation) the result is 0.
    """
    x = np.asarray(source_TxB, dtype=np.float64)
    size = max(int(round(seconds * fps)), 1)
    mean = ndimage.uniform_filter1d(x, size, axis=0, mode="nearest")
    mean_sq = ndimage.uniform_filter1d(x * x, size, axis=0, mode="nearest")
    std = np.sqrt(np.maximum(mean_sq - mean * mean, 0.0))
    return np.where(std > eps, (x - mean) / np.where(std > eps, std, 1.0), 0.0)


def butterworth(source_TxB: np.ndarray, fps: float, cutoff_hz: float = BUTTER_CUTOFF_HZ,
                order: int = BUTTER_ORDER) -> np.ndarray:
    """Zero-phase (forward-backward) Butterworth low-pass along frames.

    When the cutoff is at or above the Nyquist frequency (``fps <= 8`` for 4 Hz) nothing can be
    removed and the input is returned unchanged.
    """
    x = np.asarray(source_TxB, dtype=np.float64)
    nyquist = fps / 2.0
    if cutoff_hz >= nyquist or len(x) < 2:
        return x.copy()
    b, a = signal.butter(order, cutoff_hz / nyquist)
    padlen = min(3 * max(len(a), len(b)), len(x) - 1)
    return signal.filtfilt(b, a, x, axis=0, padlen=padlen)


def window_speed(local_TxBx3: np.ndarray, fps: float, seconds: float = VELOCITY_SECONDS) -> np.ndarray:
    """``(T, B)`` mean speed of each bone in the character frame over a centred window."""
    speed = contacts_lib.joint_speeds(local_TxBx3, fps)
    size = max(int(round(seconds * fps)), 1)
    return ndimage.uniform_filter1d(speed, size, axis=0, mode="nearest")


def phase_features(amplitude_TxB: np.ndarray, phase_TxB: np.ndarray, velocity_TxB: np.ndarray) -> np.ndarray:
    """Eq. 1: ``(T, B, 2)`` = ``|v_w| A (sin 2 pi phase, cos 2 pi phase)``."""
    angle = 2.0 * np.pi * np.asarray(phase_TxB)
    scale = np.asarray(velocity_TxB) * np.asarray(amplitude_TxB)
    return scale[..., None] * np.stack([np.sin(angle), np.cos(angle)], axis=-1)


@dataclass(frozen=True)
class LocalPhases:
    """Local phases of a clip; arrays are ``(T, B)`` over the bones in ``bones`` unless noted.

    Attributes:
      bones: joint names, by default (right hand, left hand, right foot, left foot) as in the
        2022 paper's Figure 4.
      sources: which source each bone used, ``"contact"`` or ``"free"``.
      raw_source: the source function before normalisation.
      source: normalised and smoothed source, the signal that was fitted.
      amplitude, frequency (Hz), phase (cycles, ``[0, 1)``), offset: the per-frame fit.
      velocity: ``|v_w|`` in m/s.
      features: ``(T, B, 2)`` Eq. 1 phase features (the 2022 network's 8 local-phase inputs
        for 4 bones, once flattened).
      contacts: ``(T, 2)`` foot contact labels (left, right) by the 2022 rule.
      fps: frame rate.
    """

    bones: tuple[str, ...]
    sources: tuple[str, ...]
    raw_source: np.ndarray
    source: np.ndarray
    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray
    offset: np.ndarray
    velocity: np.ndarray
    features: np.ndarray
    contacts: np.ndarray
    fps: float

    @property
    def fitted(self) -> np.ndarray:
        """``(T, B)`` the fitted sinusoid evaluated at each frame: ``A sin(2 pi phase) + B``."""
        return self.amplitude * np.sin(2.0 * np.pi * self.phase) + self.offset


def default_bones(motion: Motion) -> list[str]:
    """Right hand, left hand, right foot (ankle), left foot, found by name."""
    found = skeleton.find_feet_and_hands(motion.names, motion.source, motion.joint_map)
    (lh, rh), (la, ra) = found["hands"], found["ankles"]
    return [rh, lh, ra, la]


@dataclass(frozen=True)
class LocalPhaseConfig:
    """What :func:`local_phases` labels and how (2022 section 4.1).

    Attributes:
      bones: joints to label; ``None``: right hand, left hand, right foot (ankle), left foot.
      sources: per-bone override, ``{"LeftAnkle": "free"}``; ``"contact"`` is only valid for the
        two foot bones found by name (or given as ``feet``).
      foot_source: ``"contact"`` (paper default), ``"free"`` (hopping styles), or ``"auto"``: a
        foot whose contact starts number under half the other foot's (it seldom touches down,
        e.g. the lifted leg of a hopping style) uses the contact-free source.
      contacts: the contact test (:class:`jaxstyle.labels.contacts.ContactConfig`; the paper's
        thresholds; its ``rule``, ``"scaled"`` by default, is the same as the paper's on 100STYLE).
      sinusoid: the fit (:class:`jaxstyle.labels.sinusoid.SinusoidConfig`), here with the amplitude
        bound :data:`MAX_AMPLITUDE` (``max_amplitude=None`` fits without one) and, when its
        ``window`` is ``None``, 0.5 s windows.
    """

    bones: Sequence[str] | None = None
    sources: Mapping[str, str] | None = None
    foot_source: str = "contact"
    contacts: contacts_lib.ContactConfig = contacts_lib.ContactConfig()
    sinusoid: SinusoidConfig = SinusoidConfig(max_amplitude=MAX_AMPLITUDE)


def local_phases(motion: Motion, config: LocalPhaseConfig = LocalPhaseConfig(), *,
                 units_per_meter: float | None = None, feet: contacts_lib.FootJoints | None = None,
                 positions_TxJx3: np.ndarray | None = None) -> LocalPhases:
    """Local phases of the hands and feet of a clip (2022 paper section 4.1).

    Args:
      motion: one clip (the PCA of the contact-free source is taken over it, i.e. per style x gait).
      config: bones, sources, contact test and sinusoid fit (:class:`LocalPhaseConfig`).
      units_per_meter: file units per metre; when omitted, the contact rule's
        (:func:`jaxstyle.labels.contacts.contact_units_per_meter`), also used for the
        contact-free source's metres.
      feet: ankle and toe joints for contacts; found by name when omitted.
      positions_TxJx3: global joint positions, if already computed.
    """
    bones, sources, foot_source = config.bones, config.sources, config.foot_source
    contact_rule = config.contacts.rule
    if foot_source not in SOURCES + ("auto",):
        raise ValueError(f"foot_source must be 'contact', 'free' or 'auto', got {foot_source!r}")
    bones = default_bones(motion) if bones is None else list(bones)
    feet = feet or contacts_lib.FootJoints.find(motion)
    ankle_names = [motion.names[i] for i in feet.ankles]  # left, right
    upm = (contacts_lib.contact_units_per_meter(motion, contact_rule, feet) if units_per_meter is None
           else float(units_per_meter))

    g_pos = kinematics.global_positions(motion) if positions_TxJx3 is None else positions_TxJx3
    if not np.isfinite(g_pos).all():
        raise MotionDataError("joint positions contain NaN or infinity", motion.source)
    fc = contacts_lib.foot_contacts(motion, config.contacts, units_per_meter=upm, feet=feet, positions_TxJx3=g_pos)
    foot = fc.foot  # (T, 2) left, right

    chosen = []
    starts = [len(contacts_lib.contact_starts(foot[:, k])) for k in range(2)]
    for name in bones:
        src = "free"
        if name in ankle_names:
            side = ankle_names.index(name)
            src = foot_source
            if foot_source == "auto":
                src = "free" if 2 * starts[side] < starts[1 - side] else "contact"
        if sources and name in sources:
            src = sources[name]
            if src not in SOURCES:
                raise ValueError(f"source for {name!r} must be 'contact' or 'free', got {src!r}")
            if src == "contact" and name not in ankle_names:
                raise ValueError(f"{name!r} is not a foot bone ({', '.join(ankle_names)}); it has no contact source")
        chosen.append(src)
    unknown = [b for b in bones if b not in motion.names]
    if unknown:
        raise MotionDataError(f"unknown joint(s) {unknown}; the skeleton has {', '.join(motion.names)}", motion.source)

    idx = motion.joint_indices(bones)
    frames = character_frames(motion, smooth_seconds=0.0, positions_TxJx3=g_pos)
    local = to_local(g_pos[:, idx], frames) / upm  # metres, in the (unsmoothed) character frame
    free = contact_free_source(local)
    raw = np.empty_like(free)
    for b, (name, src) in enumerate(zip(bones, chosen, strict=True)):
        raw[:, b] = foot[:, ankle_names.index(name)].astype(np.float64) if src == "contact" else free[:, b]

    normalised = window_normalise(raw, motion.fps, eps=1e-6)
    smooth = butterworth(normalised, motion.fps)
    fit_config = config.sinusoid
    if not fit_config.window:
        fit_config = dataclasses.replace(fit_config, window=window_frames(motion.fps))
    fit: SinusoidFit = fit_sinusoids(smooth, motion.fps, fit_config)
    velocity = window_speed(local, motion.fps)
    features = phase_features(fit.amplitude, fit.phase, velocity)
    return LocalPhases(bones=tuple(bones), sources=tuple(chosen), raw_source=raw, source=smooth,
                       amplitude=fit.amplitude, frequency=fit.frequency, phase=fit.phase, offset=fit.offset,
                       velocity=velocity, features=features, contacts=foot, fps=float(motion.fps))
