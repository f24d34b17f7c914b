"""Least-squares Bezier approximation of functions [0, 1] -> R^d with exact end points.

Used to bring a high-degree trimming piece (e.g. an OCCT intersection pcurve of degree 8) down to a low
degree before composition. The caller judges the fit with its own ``error_fn`` (for a pcurve: the 3D
deviation through the surface), so this module never decides what "close" means.

Method: constrained linear least squares in the Bernstein basis (Piegl & Tiller, "The NURBS Book",
section 9.4.1, with the end points as equality constraints), sampled at Chebyshev-Lobatto nodes to tame
the Runge effect at higher degree.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .bernstein import basis
from .bezier import curve_eval

__all__ = ["fit_curve", "fit_piecewise", "fit_points", "sampled_error"]


def _nodes(k: int) -> np.ndarray:
    """k Chebyshev-Lobatto nodes on [0, 1] (0 and 1 included, exactly)."""
    x = 0.5 - 0.5 * np.cos(np.pi * np.arange(k) / (k - 1))
    x[0], x[-1] = 0.0, 1.0
    return x


def sampled_error(samples_fn: Callable[[np.ndarray], np.ndarray], n: int = 1001):
    """An ``error_fn`` for :func:`fit_curve`: max Euclidean distance to samples_fn on n uniform points.

    This is a sampled estimate, not a bound. Returns ``error_fn(ctrl) -> float``.
    """
    t = np.linspace(0.0, 1.0, n)
    ref = np.asarray(samples_fn(t), dtype=float)

    def error_fn(ctrl: np.ndarray) -> float:
        return float(np.max(np.linalg.norm(curve_eval(ctrl, t) - ref, axis=-1)))

    return error_fn


def fit_points(t: np.ndarray, pts: np.ndarray, degree: int, p0=None, p1=None) -> np.ndarray:
    """Least-squares Bezier fit of points ``pts`` (k, d) at parameters ``t`` (k,), with ctrl[0] =
    pts[0] (or p0) and ctrl[-1] = pts[-1] (or p1) held. Returns (degree+1, d)."""
    f = np.asarray(pts, dtype=float)
    if f.ndim != 2 or f.shape[0] != len(t):
        raise ValueError(f"points must be (len(t), d), got shape {f.shape}")
    start = f[0] if p0 is None else np.asarray(p0, dtype=float)
    end = f[-1] if p1 is None else np.asarray(p1, dtype=float)
    ctrl = np.empty((degree + 1, f.shape[1]))
    ctrl[0], ctrl[-1] = start, end
    if degree >= 2:
        b = basis(degree, t)
        rhs = f - b[:, :1] * start[None, :] - b[:, -1:] * end[None, :]
        ctrl[1:-1] = np.linalg.lstsq(b[:, 1:-1], rhs, rcond=None)[0]
    return ctrl


def _lsq_fixed_ends(samples_fn, degree: int, n_samples: int, p0=None, p1=None) -> np.ndarray:
    """Least-squares Bezier fit with ctrl[0] = f(0) (or p0) and ctrl[-1] = f(1) (or p1). (degree+1, d)."""
    t = _nodes(n_samples)
    return fit_points(t, samples_fn(t), degree, p0, p1)


def fit_curve(
    samples_fn: Callable[[np.ndarray], np.ndarray],
    degree: int,
    tol: float,
    error_fn: Callable[[np.ndarray], float] | None = None,
    n_samples: int | None = None,
) -> tuple[np.ndarray, float] | None:
    """Fit a polynomial Bezier curve of the given degree to a function [0, 1] -> R^d.

    The end points are interpolated exactly: ctrl[0] = samples_fn([0])[0], ctrl[-1] = samples_fn([1])[0]
    (both taken from the one sampling call, so they equal samples_fn's values bit for bit).

    Parameters
    ----------
    samples_fn : callable t (k,) -> (k, d) float.
    degree : int >= 1.
    tol : float; the fit is accepted when error_fn(ctrl) <= tol.
    error_fn : callable ctrl (degree+1, d) -> float, supplied by the caller (e.g. 3D deviation through a
        surface for a pcurve). Default: :func:`sampled_error` on 1001 uniform points (an estimate).
    n_samples : number of Chebyshev-Lobatto sample points (default max(64, 8 (degree+1))).

    Returns
    -------
    (ctrl : (degree+1, d) float, err : float) or None if err > tol.
    """
    if degree < 1:
        raise ValueError(f"fit_curve: degree must be >= 1, got {degree}")
    if n_samples is None:
        n_samples = max(64, 8 * (degree + 1))
    if n_samples < degree + 1:
        raise ValueError(f"fit_curve: n_samples={n_samples} < degree+1={degree + 1}")
    ctrl = _lsq_fixed_ends(samples_fn, degree, n_samples)
    if error_fn is None:
        error_fn = sampled_error(samples_fn)
    err = float(error_fn(ctrl))
    if not err <= tol:  # also rejects nan
        return None
    return ctrl, err


def fit_piecewise(
    samples_fn: Callable[[np.ndarray], np.ndarray],
    degree: int,
    tol: float,
    error_fn: Callable[[np.ndarray, float, float], float] | None = None,
    max_pieces: int = 64,
    n_samples: int | None = None,
    a: float = 0.0,
    b: float = 1.0,
) -> tuple[np.ndarray, list[np.ndarray], list[float]] | None:
    """Piecewise Bezier fit of f on [a, b], bisecting pieces at their midpoints until each meets tol.

    Every piece interpolates f at its two breakpoints; neighbouring pieces share the very same end
    point array values (f evaluated once per breakpoint), so the result is C0 exactly.

    Parameters
    ----------
    samples_fn : callable w (k,) -> (k, d) float on the global parameter [a, b].
    error_fn : callable (ctrl (degree+1, d), w0, w1) -> float, the error of a piece fitted on
        [w0, w1] (its local parameter 0..1 maps to w0..w1). Default: sampled distance to f (an estimate).
    max_pieces : give up (return None) rather than exceed this many pieces.

    Returns
    -------
    (breaks : (k+1,) float, pieces : list of k (degree+1, d) arrays, errs : list of k floats) or None.
    """
    if degree < 1:
        raise ValueError(f"fit_piecewise: degree must be >= 1, got {degree}")
    if not b > a:
        raise ValueError(f"fit_piecewise: need a < b, got [{a}, {b}]")
    if n_samples is None:
        n_samples = max(64, 8 * (degree + 1))
    end_cache: dict[float, np.ndarray] = {}

    def point(w: float) -> np.ndarray:
        if w not in end_cache:
            end_cache[w] = np.asarray(samples_fn(np.array([w])), dtype=float)[0]
        return end_cache[w]

    def local(w0: float, w1: float):
        # (1 - t) w0 + t w1 is exactly w0 at t = 0 and exactly w1 at t = 1.
        return lambda t: samples_fn((1.0 - t) * w0 + t * w1)

    def piece_error(ctrl: np.ndarray, w0: float, w1: float) -> float:
        if error_fn is not None:
            return float(error_fn(ctrl, w0, w1))
        return sampled_error(local(w0, w1), 257)(ctrl)

    todo = [(float(a), float(b))]
    done: list[tuple[float, float, np.ndarray, float]] = []
    while todo:
        w0, w1 = todo.pop()
        ctrl = _lsq_fixed_ends(local(w0, w1), degree, n_samples, point(w0), point(w1))
        err = piece_error(ctrl, w0, w1)
        if err <= tol:
            done.append((w0, w1, ctrl, err))
            continue
        wm = 0.5 * (w0 + w1)
        if len(done) + len(todo) + 2 > max_pieces or not (w0 < wm < w1):
            return None
        todo.append((wm, w1))
        todo.append((w0, wm))
    done.sort(key=lambda x: x[0])
    breaks = np.array([d[0] for d in done] + [done[-1][1]])
    return breaks, [d[2] for d in done], [d[3] for d in done]
