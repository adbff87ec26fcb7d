"""Per-frame sinusoid fits over sliding windows, vectorised in JAX (2022 paper section 4.1.4).

For every frame ``i`` and signal ``b`` the model ``A sin(2 pi (F t - S)) + B`` is fitted by least
squares to the ``W`` samples of a window centred on ``i`` (``W = 31`` at 60 fps in the paper),
with ``F`` in ``[f_min, f_max]`` (0.25-4 Hz). The phase of frame ``i`` is ``F t_i - S`` in cycles.

How (no iterative optimiser, no loop over frames):

1. With time measured from the window centre, ``A sin(2 pi (F tau) + theta) + B`` is linear in
   ``(a, c, B) = (A cos theta, A sin theta, B)`` for a fixed ``F``. For a grid of ``K``
   frequencies, all windows and signals, the normal equations are built with a few matrix
   products and the 2x2 systems (after removing the window mean, which is what ``B`` absorbs)
   solved in closed form; the residual sum of squares picks the best grid frequency.
2. A parabola through the residuals at the best grid point and its two neighbours refines ``F``
   (``refine`` times, halving the step), and the linear problem is solved once more there.
3. ``A = |(a, c)|`` and the phase at the window centre is ``theta / 2 pi`` (mod 1).

Samples outside the clip are masked out (windows at the clip ends are shorter, not padded). A
window with no variation gets ``A = 0`` and phase 0 rather than NaN, and so does a window whose
sine and cosine columns are numerically collinear (too few samples to fit a sinusoid).

Conditioning: a 0.5 s window holds only 1/8 of a cycle at 0.25 Hz, where a sinusoid looks like a
parabola; such fits are well posed only without noise. Synthetic sinusoids are recovered within
0.01 cycles from 0.3 Hz up (see the tests); in real data these windows have low amplitude.

``scipy.optimize.curve_fit`` fits the same model one window at a time; the tests use it as the
reference and ``benchmarks/phases.py`` compares speeds.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

F_MIN_HZ = 0.25
F_MAX_HZ = 4.0
WINDOW_SECONDS = 0.5  # 31 frames at 60 fps, the paper's window
STILL_TOLERANCE = 1e-5  # relative spread below which a window counts as constant
DET_TOLERANCE = 1e-6  # relative: sine and cosine columns more than 99.9999% collinear


class SinusoidFit(NamedTuple):
    """Per-frame, per-signal fit results, each ``(T, B)``: ``A``, ``F`` (Hz), phase (cycles, in
    ``[0, 1)``) and offset ``B``."""

    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray
    offset: np.ndarray


def window_frames(fps: float, seconds: float = WINDOW_SECONDS) -> int:
    """Odd window length spanning ``seconds`` (31 frames at 60 fps as in the paper, 61 at 120 fps,
    17 at 30 fps), so the fit sees the same stretch of time whatever the frame rate."""
    return 2 * int(round(seconds * fps / 2.0)) + 1


def _sums(w_NxW, y_NxBxW, s_NxKxW, c_NxKxW):
    """Masked, mean-removed normal equations for all frames, signals and frequencies."""
    n = jnp.maximum(jnp.sum(w_NxW, axis=-1), 1.0)  # (N,)
    ms = jnp.einsum("nw,nkw->nk", w_NxW, s_NxKxW) / n[:, None]
    mc = jnp.einsum("nw,nkw->nk", w_NxW, c_NxKxW) / n[:, None]
    my = jnp.einsum("nw,nbw->nb", w_NxW, y_NxBxW) / n[:, None]
    yc = (y_NxBxW - my[..., None]) * w_NxW[:, None, :]  # samples outside the clip weigh 0
    sc = (s_NxKxW - ms[..., None]) * w_NxW[:, None, :]
    cc = (c_NxKxW - mc[..., None]) * w_NxW[:, None, :]
    g_ss = jnp.sum(sc * sc, -1)
    g_cc = jnp.sum(cc * cc, -1)
    g_sc = jnp.sum(sc * cc, -1)
    b_s = jnp.einsum("nbw,nkw->nbk", yc, sc)
    b_c = jnp.einsum("nbw,nkw->nbk", yc, cc)
    yy = jnp.sum(yc * yc, -1)  # (N, B)
    return g_ss, g_cc, g_sc, b_s, b_c, yy


def _solve(g_ss, g_cc, g_sc, b_s, b_c):
    """Closed-form 2x2 solve; a (near-)singular system (a window too short to tell sine from
    cosine, or with no samples) gives zero coefficients instead of NaN or a huge amplitude."""
    det = g_ss * g_cc - g_sc * g_sc
    ok = det > DET_TOLERANCE * g_ss * g_cc + jnp.finfo(det.dtype).tiny
    inv_det = jnp.where(ok, 1.0 / jnp.where(ok, det, 1.0), 0.0)
    a = (g_cc * b_s - g_sc * b_c) * inv_det
    c = (g_ss * b_c - g_sc * b_s) * inv_det
    return a, c


def _fit_grid(y_NxBxW, w_NxW, tau_W, freqs_K, max_amplitude):
    """Scores ``(N, B, K)`` (residuals, see :func:`_score`) for every frame, signal and frequency."""
    arg = 2.0 * jnp.pi * freqs_K[:, None] * tau_W[None, :]  # (K, W)
    n_frames = w_NxW.shape[0]
    s = jnp.broadcast_to(jnp.sin(arg), (n_frames,) + arg.shape)
    c = jnp.broadcast_to(jnp.cos(arg), (n_frames,) + arg.shape)
    g_ss, g_cc, g_sc, b_s, b_c, yy = _sums(w_NxW, y_NxBxW, s, c)
    g_ss, g_cc, g_sc = g_ss[:, None], g_cc[:, None], g_sc[:, None]
    # On the grid a too-large fit is only scaled onto the bound (an upper bound on the
    # constrained residual, and cheap); refinement and the final fit solve exactly.
    a, cc = _bounded_solve(g_ss, g_cc, g_sc, b_s, b_c, max_amplitude, iterations=0)
    return _residual(yy[..., None], a, cc, b_s, b_c, g_ss, g_cc, g_sc)  # (N, B, K)


def _bounded_solve(g_ss, g_cc, g_sc, b_s, b_c, max_amplitude, iterations: int = 8):
    """Least squares for ``(a, c)`` subject to ``|(a, c)| <= max_amplitude``.

    When the free solution is too large, the constrained one is ``(G + lambda I)^-1 b`` with the
    ``lambda >= 0`` that puts it on the bound, found by Newton's method on the secular equation
    ``1/|x(lambda)| = 1/r`` (More & Sorensen), which converges monotonically from 0. A final
    radial scaling makes the bound exact.
    """
    a, c = _solve(g_ss, g_cc, g_sc, b_s, b_c)
    r = jnp.where(jnp.isfinite(max_amplitude), max_amplitude, 1.0)
    over = (a * a + c * c > max_amplitude * max_amplitude) & jnp.isfinite(max_amplitude)
    lam = jnp.zeros_like(a)
    for _ in range(iterations):
        xa, xc = _solve(g_ss + lam, g_cc + lam, g_sc, b_s, b_c)
        norm = jnp.sqrt(xa * xa + xc * xc)
        qa, qc = _solve(g_ss + lam, g_cc + lam, g_sc, xa, xc)
        xq = xa * qa + xc * qc
        step = jnp.where(xq > 0, (norm - r) / r * norm * norm / jnp.where(xq > 0, xq, 1.0), 0.0)
        lam = jnp.maximum(lam + step, 0.0)
    xa, xc = _solve(g_ss + lam, g_cc + lam, g_sc, b_s, b_c)
    norm = jnp.sqrt(xa * xa + xc * xc)
    shrink = jnp.where(norm > r, r / jnp.where(norm > 0, norm, 1.0), 1.0)
    return jnp.where(over, xa * shrink, a), jnp.where(over, xc * shrink, c)


def _residual(yy, a, c, b_s, b_c, g_ss, g_cc, g_sc):
    """Residual sum of squares of the (mean-removed) fit ``(a, c)``; exact for any ``(a, c)``."""
    return yy - 2.0 * (a * b_s + c * b_c) + a * a * g_ss + 2.0 * a * c * g_sc + c * c * g_cc


def _fit_at(y_NxBxW, w_NxW, tau_W, f_NxB, max_amplitude):
    """Solve the linear problem at one frequency per frame and signal; returns residuals too."""
    arg = 2.0 * jnp.pi * f_NxB[..., None] * tau_W  # (N, B, W)
    s, c = jnp.sin(arg), jnp.cos(arg)
    n = jnp.maximum(jnp.sum(w_NxW, axis=-1), 1.0)[:, None]  # (N, 1)
    w = w_NxW[:, None, :]
    ms, mc = jnp.sum(w * s, -1) / n, jnp.sum(w * c, -1) / n
    my = jnp.sum(w * y_NxBxW, -1) / n
    yc, sc, cc = (y_NxBxW - my[..., None]) * w, (s - ms[..., None]) * w, (c - mc[..., None]) * w
    g_ss = jnp.sum(sc * sc, -1)
    g_cc = jnp.sum(cc * cc, -1)
    g_sc = jnp.sum(sc * cc, -1)
    b_s, b_c = jnp.sum(yc * sc, -1), jnp.sum(yc * cc, -1)
    a, c_coef = _bounded_solve(g_ss, g_cc, g_sc, b_s, b_c, max_amplitude)
    yy = jnp.sum(yc * yc, -1)
    sse = _residual(yy, a, c_coef, b_s, b_c, g_ss, g_cc, g_sc)
    # A window whose spread is at rounding level of its mean has no movement: no sinusoid.
    still = yy <= n * (STILL_TOLERANCE * jnp.abs(my)) ** 2 + jnp.finfo(yy.dtype).tiny
    a, c_coef = jnp.where(still, 0.0, a), jnp.where(still, 0.0, c_coef)
    offset = my - a * ms - c_coef * mc  # B: the model's value minus the sinusoid at the mean
    return a, c_coef, offset, sse


@functools.partial(jax.jit, static_argnames=("refine",))
def fit_windows(y_NxBxW: jax.Array, w_NxW: jax.Array, tau_W: jax.Array, freqs_K: jax.Array,
                max_amplitude: jax.Array | float = jnp.inf,
                refine: int = 2) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Fit ``A sin(2 pi F tau + theta) + B`` to windows; returns ``(A, F, phase, B)``, each ``(N, B)``.

    Args:
      y_NxBxW: ``N`` windows of ``B`` signals, ``W`` samples each (masked samples may hold anything finite).
      w_NxW: 1 for samples inside the clip, 0 outside.
      tau_W: sample times in seconds relative to the window centre (where the phase is read).
      freqs_K: increasing, evenly spaced frequency grid in Hz.
      max_amplitude: bound on ``A`` (an array, so it can be swept). At each frequency the
        linear problem is solved under the bound (:func:`_bounded_solve`), so the frequency
        search compares admissible fits only.
      refine: parabolic refinement steps after the grid search.

    Pure and jittable; vmap it over further axes if needed.
    """
    score = _fit_grid(y_NxBxW, w_NxW, tau_W, freqs_K, max_amplitude)
    k = jnp.argmin(score, axis=-1)  # (N, B)
    num_k = freqs_K.shape[0]
    step = (freqs_K[-1] - freqs_K[0]) / jnp.maximum(num_k - 1, 1)
    f = freqs_K[k]
    km, kp = jnp.clip(k - 1, 0, num_k - 1), jnp.clip(k + 1, 0, num_k - 1)
    s0 = jnp.take_along_axis(score, k[..., None], -1)[..., 0]
    sm = jnp.take_along_axis(score, km[..., None], -1)[..., 0]
    sp = jnp.take_along_axis(score, kp[..., None], -1)[..., 0]
    f_lo, f_hi = freqs_K[0], freqs_K[-1]

    def score_at(freq):
        return _fit_at(y_NxBxW, w_NxW, tau_W, freq, max_amplitude)[3]

    for _ in range(refine):
        curv = sm - 2.0 * s0 + sp
        delta = jnp.where(curv > 0, 0.5 * (sm - sp) / jnp.where(curv > 0, curv, 1.0), 0.0)
        f = jnp.clip(f + jnp.clip(delta, -1.0, 1.0) * step, f_lo, f_hi)
        step = step / 2.0
        sm, s0, sp = score_at(jnp.clip(f - step, f_lo, f_hi)), score_at(f), score_at(jnp.clip(f + step, f_lo, f_hi))
    a, c, offset, _ = _fit_at(y_NxBxW, w_NxW, tau_W, f, max_amplitude)
    amplitude = jnp.sqrt(a * a + c * c)
    phase = jnp.mod(jnp.arctan2(c, a) / (2.0 * jnp.pi), 1.0)
    phase = jnp.where(amplitude > 0, phase, 0.0)
    return amplitude, f, phase, offset


def sliding_windows(signal_TxB: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """``(T, B, W)`` windows centred on each frame (zeros outside the clip) and ``(T, W)`` masks."""
    sig = np.asarray(signal_TxB)
    num_frames = sig.shape[0]
    half = window // 2
    padded = np.zeros((num_frames + 2 * half,) + sig.shape[1:], dtype=sig.dtype)
    padded[half:half + num_frames] = sig
    idx = np.arange(num_frames)[:, None] + np.arange(window)[None, :]  # (T, W)
    windows = np.moveaxis(padded[idx], 1, -1)  # (T, B, W)
    mask = ((idx >= half) & (idx < half + num_frames)).astype(sig.dtype)
    return windows, mask


@dataclasses.dataclass(frozen=True)
class SinusoidConfig:
    """Settings of the windowed sinusoid fit (2022 section 4.1.4).

    Attributes:
      window: samples per window (odd); ``None``: 31 at 60 fps (:func:`window_frames`).
      f_min, f_max: frequency range in Hz (paper: 0.25-4).
      num_freqs: grid size before refinement.
      max_amplitude: optional bound on ``A`` (see :func:`fit_windows`); ``None`` leaves it free.
      refine: parabolic refinement steps.
      chunk: frames per jitted call (bounds memory; every call has the same shape, so it compiles once).
    """

    window: int | None = None
    f_min: float = F_MIN_HZ
    f_max: float = F_MAX_HZ
    num_freqs: int = 64
    max_amplitude: float | None = None
    refine: int = 2
    chunk: int = 4096


def fit_sinusoids(signal_TxB: np.ndarray, fps: float, config: SinusoidConfig = SinusoidConfig()) -> SinusoidFit:
    """Fit a sinusoid around every frame of each column of ``signal_TxB`` (2022 section 4.1.4).

    Args:
      signal_TxB: source functions, frames x signals.
      fps: frame rate; times are in seconds so ``F`` is in Hz.
      config: window, frequency grid, amplitude bound, refinement and chunk (:class:`SinusoidConfig`).
    """
    window, f_min, f_max, max_amplitude = config.window, config.f_min, config.f_max, config.max_amplitude
    sig = np.asarray(signal_TxB, dtype=np.float32)
    squeeze = sig.ndim == 1
    if squeeze:
        sig = sig[:, None]
    if sig.ndim != 2:
        raise ValueError(f"signal must have shape (T,) or (T, B), got {np.shape(signal_TxB)}")
    if not np.isfinite(sig).all():
        raise ValueError("signal contains NaN or infinity")
    if not 0 < f_min < f_max:
        raise ValueError(f"need 0 < f_min < f_max, got {f_min}, {f_max}")
    window = window_frames(fps) if window is None else int(window)
    if window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd number of frames >= 3, got {window}")
    half = window // 2
    tau = jnp.asarray((np.arange(window) - half) / fps, dtype=jnp.float32)
    freqs = jnp.asarray(np.linspace(f_min, f_max, config.num_freqs), dtype=jnp.float32)
    if max_amplitude is not None and not max_amplitude > 0:
        raise ValueError(f"max_amplitude must be positive, got {max_amplitude}")
    a_max = jnp.asarray(np.inf if max_amplitude is None else max_amplitude, dtype=jnp.float32)
    num_frames = sig.shape[0]
    # Pad every call to a power-of-two size (at least 256, at most ``chunk``) so clips of
    # different lengths share a handful of compiled shapes.
    chunk = min(max(256, 1 << max(num_frames - 1, 1).bit_length()), max(config.chunk, 256))
    outs = []
    for start in range(0, num_frames, chunk):
        lo, hi = max(start - half, 0), min(start + chunk + half, num_frames)
        windows, mask = sliding_windows(sig[lo:hi], window)
        windows, mask = windows[start - lo:start - lo + chunk], mask[start - lo:start - lo + chunk]
        # A window that reaches past the chunk but not past the clip is whole: sliding_windows
        # saw the neighbouring frames because the slice was widened by half a window.
        n = windows.shape[0]
        if n < chunk:  # pad the last chunk to the common shape (padded rows are discarded)
            windows = np.concatenate([windows, np.zeros((chunk - n,) + windows.shape[1:], windows.dtype)])
            mask = np.concatenate([mask, np.ones((chunk - n, window), mask.dtype)])
        res = fit_windows(jnp.asarray(windows), jnp.asarray(mask), tau, freqs, a_max, refine=config.refine)
        outs.append([np.asarray(r)[:n] for r in res])
    amp, freq, phase, offset = (np.concatenate([o[i] for o in outs]) for i in range(4))
    if squeeze:
        amp, freq, phase, offset = amp[:, 0], freq[:, 0], phase[:, 0], offset[:, 0]
    return SinusoidFit(amp.astype(np.float64), freq.astype(np.float64), phase.astype(np.float64),
                       offset.astype(np.float64))
