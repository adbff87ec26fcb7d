"""Independent reference for the sinusoid fit: scipy.optimize.curve_fit, one window at a time.

Shares no code with jaxstyle.labels.sinusoid. Used by the tests (agreement) and by
benchmarks/phases.py (the loop the vectorised fit is compared against).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import curve_fit


def model(t, amplitude, frequency, shift, offset):
    return amplitude * np.sin(2.0 * np.pi * (frequency * t - shift)) + offset


def fit_window(t: np.ndarray, y: np.ndarray, f_min: float = 0.25, f_max: float = 4.0, a_max: float = np.inf,
               starts: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0)) -> tuple[float, float, float, float, float]:
    """Best of several curve_fit runs: ``(A, F, phase at t = 0 in cycles, B, residual sum of squares)``."""
    best = None
    for f0 in starts:
        p0 = [min(max(np.std(y) * np.sqrt(2.0), 1e-6), 0.99 * a_max), f0, 0.0, float(np.mean(y))]
        try:
            bounds = ([0.0, f_min, -np.inf, -np.inf], [a_max, f_max, np.inf, np.inf])
            p, _ = curve_fit(model, t, y, p0=p0, bounds=bounds, maxfev=2000)
        except (RuntimeError, ValueError):
            continue
        sse = float(np.sum((model(t, *p) - y) ** 2))
        if best is None or sse < best[-1]:
            best = (p[0], p[1], float(np.mod(-p[2], 1.0)), p[3], sse)
    if best is None:
        raise RuntimeError("curve_fit failed from every start")
    return best
