"""Plots of labelled motion (matplotlib, imported lazily so the core never needs a display)."""

from __future__ import annotations

import numpy as np

from jaxstyle.labels.local_phase import LocalPhases


def plot_local_phases(result: LocalPhases, start: int = 0, stop: int | None = None, *, title: str = "",
                      marker: int | None = None):
    """A figure like the 2022 paper's Figure 4 for frames ``[start, stop)`` of a clip.

    One row per bone (right hand, left hand, right foot, left foot by default): the normalised,
    smoothed source function (white), the fitted sinusoid (dashed), the phase as a saw-tooth
    whose opacity is the Eq. 1 magnitude ``|v_w| A`` (blue), and foot contacts (green bars).
    ``marker`` draws a vertical line at that frame. Returns the matplotlib ``Figure``.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    stop = result.phase.shape[0] if stop is None else stop
    frames = np.arange(start, stop)
    t = frames / result.fps
    num_bones = len(result.bones)
    magnitude = result.velocity * result.amplitude
    scale = max(float(np.percentile(magnitude, 99)), 1e-9)
    fig, axes = plt.subplots(num_bones, 1, figsize=(11, 1.7 * num_bones), sharex=True, squeeze=False)
    fig.patch.set_facecolor("#1e1e1e")
    feet = {}
    if result.contacts.shape[1] == 2 and num_bones == 4:
        feet = {2: 1, 3: 0}  # right foot row -> right contacts, left foot row -> left contacts
    for b, ax in enumerate(axes[:, 0]):
        ax.set_facecolor("#2b2b2b")
        src = result.source[frames, b]
        lo, hi = float(min(src.min(), -1.5)), float(max(src.max(), 1.5))
        if b in feet:
            contact = result.contacts[frames, feet[b]]
            ax.fill_between(t, lo, hi, where=contact, color="#3fb950", alpha=0.25, step="mid", lw=0)
        # phase saw-tooth scaled into the plot, opacity = magnitude
        ph = lo + (hi - lo) * result.phase[frames, b]
        pts = np.stack([t, ph], -1)
        segs = np.stack([pts[:-1], pts[1:]], 1)
        jump = np.abs(np.diff(result.phase[frames, b])) > 0.5
        alpha = np.clip(magnitude[frames[:-1], b] / scale, 0.0, 1.0)
        colors = np.zeros((len(segs), 4))
        colors[:] = (0.35, 0.6, 1.0, 0.0)
        colors[:, 3] = np.where(jump, 0.0, alpha)
        ax.add_collection(LineCollection(segs, colors=colors, linewidths=1.5))
        ax.plot(t, src, color="white", lw=1.2, label="source")
        ax.plot(t, result.fitted[frames, b], color="#f0883e", lw=0.8, ls="--", label="fitted sinusoid")
        if marker is not None and start <= marker < stop:
            ax.axvline(marker / result.fps, color="#e3b341", lw=1)
        ax.set_ylim(lo, hi)
        ax.set_ylabel(f"{result.bones[b]}\n({result.sources[b]})", color="white", fontsize=8)
        ax.tick_params(colors="white", labelsize=7)
    axes[-1, 0].set_xlabel("time (s)", color="white")
    axes[0, 0].legend(loc="upper right", fontsize=7, facecolor="#2b2b2b", labelcolor="white")
    if title:
        fig.suptitle(title, color="white")
    fig.tight_layout()
    return fig


def pca_2d(points_NxD: np.ndarray) -> np.ndarray:
    """``(N, 2)`` projection of points on their first two principal components."""
    x = np.asarray(points_NxD, dtype=np.float64)
    x = x - x.mean(axis=0)
    _, _, vt = np.linalg.svd(x, full_matrices=False)
    return x @ vt[:2].T


def plot_film_projection(panels: dict[str, dict[str, np.ndarray]], new_styles=(), *, title: str = ""):
    """The 2022 paper's Figure 11 with PCA instead of t-SNE: one panel per entry of ``panels``
    (e.g. ``{"before fine-tuning": {style: (n, 2048) FiLM parameters}, "after ...": ...}``), each
    projected on its own first two principal components; ``new_styles`` (held out of training) are
    drawn as large dark markers, training styles as small pastel dots. Returns the ``Figure``."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 5), squeeze=False)
    markers = ["o", "s", "^", "D", "v"]
    for ax, (name, per_style) in zip(axes[0], panels.items(), strict=True):
        styles = list(per_style)
        xy = pca_2d(np.concatenate([per_style[s] for s in styles]))
        start, k = 0, 0
        for i, s in enumerate(styles):
            n = len(per_style[s])
            pts = xy[start:start + n]
            start += n
            if s in new_styles:
                ax.scatter(pts[:, 0], pts[:, 1], s=40, marker=markers[k % len(markers)], color="black",
                           edgecolor="white", label=f"{s} (new)", zorder=3)
                k += 1
            else:
                ax.scatter(pts[:, 0], pts[:, 1], s=12, alpha=0.6, color=plt.cm.Pastel1(i % 9), label=s)
        ax.set_title(name)
        ax.set_xticks([]), ax.set_yticks([])
        ax.legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
