"""Least-squares fitting with exact end points; the tolerance is met when a fit is returned."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.core.approx import fit_curve, fit_piecewise, sampled_error
from watertight_cli.core.bezier import curve_eval

from .helpers import seeds

DENSE = np.linspace(0, 1, 20001)


def make_fn(rng):
    """A smooth planar curve: a random trigonometric polynomial."""
    amp = rng.normal(size=(3, 2))
    freq = rng.uniform(0.5, 3.0, 3)
    phase = rng.uniform(0, 2 * np.pi, 3)

    def f(t):
        t = np.asarray(t, dtype=float)[:, None, None]
        return (amp * np.sin(freq[:, None] * 2 * np.pi * t + phase[:, None])).sum(axis=1)

    return f


def true_error(ctrl, f, a=0.0, b=1.0):
    x = DENSE
    return np.linalg.norm(curve_eval(ctrl, x) - f((1 - x) * a + x * b), axis=1).max()


@settings(max_examples=30, deadline=None)
@given(seeds, st.integers(1, 9), st.sampled_from([1e-1, 1e-3, 1e-6]))
def test_fit_curve_meets_tol_when_it_returns(seed, degree, tol):
    rng = np.random.default_rng(seed)
    f = make_fn(rng)
    res = fit_curve(f, degree, tol)
    if res is None:
        return
    ctrl, err = res
    assert err <= tol
    np.testing.assert_array_equal(ctrl[0], f(np.array([0.0]))[0])
    np.testing.assert_array_equal(ctrl[-1], f(np.array([1.0]))[0])
    # independent, 20x denser measurement; the default error_fn samples 1001 points, so allow 1 %
    assert true_error(ctrl, f) <= tol * 1.01


def test_fit_curve_exact_for_polynomials_and_custom_error_fn():
    rng = np.random.default_rng(0)
    c = rng.normal(size=(5, 3))
    res = fit_curve(lambda t: curve_eval(c, t), 4, 1e-12)
    assert res is not None
    np.testing.assert_allclose(res[0], c, atol=1e-12)
    calls = []

    def err_fn(ctrl):
        calls.append(ctrl.shape)
        return 1.0

    assert fit_curve(lambda t: curve_eval(c, t), 4, 0.5, error_fn=err_fn) is None
    assert calls == [(5, 3)]
    with pytest.raises(ValueError):
        fit_curve(lambda t: curve_eval(c, t), 0, 1.0)


@settings(max_examples=15, deadline=None)
@given(seeds, st.sampled_from([(2, 1e-2), (2, 1e-4), (3, 1e-5), (4, 1e-6), (5, 1e-7)]))
def test_fit_piecewise_c0_and_tol(seed, degree_tol):
    # pairs reachable within 256 pieces for the test functions (|f^(k)| up to ~5 (6 pi)^k)
    degree, tol = degree_tol
    rng = np.random.default_rng(seed)
    f = make_fn(rng)
    a, b = sorted(rng.uniform(-1, 2, 2))
    g = lambda w: f((np.asarray(w) - a) / (b - a))  # noqa: E731
    res = fit_piecewise(g, degree, tol, max_pieces=256, a=a, b=b)
    assert res is not None
    breaks, pieces, errs = res
    assert breaks[0] == a and breaks[-1] == b and np.all(np.diff(breaks) > 0)
    assert len(pieces) == len(breaks) - 1 == len(errs)
    for i in range(len(pieces) - 1):
        np.testing.assert_array_equal(pieces[i][-1], pieces[i + 1][0])  # C0, bit for bit
    for (w0, w1), p, e in zip(zip(breaks[:-1], breaks[1:], strict=True), pieces, errs, strict=True):
        assert e <= tol
        assert true_error(p, g, w0, w1) <= tol * 1.01


def test_fit_piecewise_gives_up():
    f = lambda t: np.stack([t, np.abs(t - 1 / 3) ** 0.5], axis=1)  # noqa: E731
    assert fit_piecewise(f, 2, 1e-12, max_pieces=8) is None


def test_sampled_error():
    f = lambda t: np.stack([t, t**2], axis=1)  # noqa: E731
    err = sampled_error(f)
    assert err(np.array([[0, 0], [0.5, 0], [1, 1]])) < 1e-15
