"""Degree reduction: the certified bound is never exceeded; elevated curves reduce back exactly."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from watertight_cli.core.bezier import curve_eval, elevate_curve, elevate_surface, surface_eval_grid
from watertight_cli.core.reduce import reduce_curve, reduce_surface, reduction_bound

from .helpers import seeds

SETTINGS = settings(max_examples=50, deadline=None)
X = np.linspace(0, 1, 2001)


@SETTINGS
@given(seeds, st.integers(1, 20), st.integers(0, 19), st.integers(1, 4))
def test_reduce_curve_bound_holds(seed, n, target, k):
    assume(target < n and 2 * k <= target + 1)
    rng = np.random.default_rng(seed)
    ctrl = rng.normal(size=(n + 1, 3))
    new, bound = reduce_curve(ctrl, target, fix_ends=k)
    assert new.shape == (target + 1, 3)
    true = np.linalg.norm(curve_eval(new, X) - curve_eval(ctrl, X), axis=1).max()
    assert true <= bound * (1 + 1e-12) + 1e-14
    np.testing.assert_array_equal(new[0], ctrl[0])
    np.testing.assert_array_equal(new[-1], ctrl[-1])
    # the first/last k elevated control points match (derivatives up to order k-1 kept)
    up = elevate_curve(new, n - target)
    np.testing.assert_allclose(up[:k], ctrl[:k], atol=1e-10 * (1 + np.abs(ctrl).max()))
    np.testing.assert_allclose(up[-k:], ctrl[-k:], atol=1e-10 * (1 + np.abs(ctrl).max()))
    assert abs(reduction_bound(ctrl, new) - bound) <= 1e-12 * (1 + bound)


@SETTINGS
@given(seeds, st.integers(1, 12), st.integers(1, 10), st.integers(1, 3))
def test_reduce_elevated_curve_returns_original(seed, target, r, k):
    assume(2 * k <= target + 1)
    rng = np.random.default_rng(seed)
    orig = rng.normal(size=(target + 1, 2))
    new, bound = reduce_curve(elevate_curve(orig, r), target, fix_ends=k)
    assert bound < 1e-12 * (1 + np.abs(orig).max())
    np.testing.assert_allclose(new, orig, atol=1e-10)


def test_reduce_curve_errors_and_trivial():
    c = np.random.default_rng(0).normal(size=(6, 3))
    with pytest.raises(ValueError):
        reduce_curve(c, 2, fix_ends=2)  # 2*2 > 2+1
    with pytest.raises(ValueError):
        reduce_curve(c, -1)
    same, b = reduce_curve(c, 5)
    assert b == 0 and np.array_equal(same, c)
    up, b = reduce_curve(c, 7)
    assert b == 0 and up.shape == (8, 3)


@settings(max_examples=30, deadline=None)
@given(seeds, st.integers(2, 10), st.integers(2, 10), st.integers(1, 8), st.integers(1, 8), st.booleans())
def test_reduce_surface_bound_holds(seed, m, n, mt, nt, fix):
    rng = np.random.default_rng(seed)
    ctrl = rng.normal(size=(m + 1, n + 1, 3))
    new, bound = reduce_surface(ctrl, mt, nt, fix_boundary=fix)
    assert new.shape == (mt + 1, nt + 1, 3)
    s = np.linspace(0, 1, 101)
    diff = surface_eval_grid(new, s, s) - surface_eval_grid(ctrl, s, s)
    assert np.linalg.norm(diff, axis=-1).max() <= bound * (1 + 1e-12) + 1e-14
    if fix:
        # boundary rows are the reduced boundary curves (same orientation -> same curve, bit for bit)
        for got, row, tgt in (
            (new[0], ctrl[0], nt),
            (new[-1], ctrl[-1], nt),
            (new[:, 0], ctrl[:, 0], mt),
            (new[:, -1], ctrl[:, -1], mt),
        ):
            np.testing.assert_array_equal(got, reduce_curve(row, tgt)[0])
        np.testing.assert_array_equal(
            new[[0, 0, -1, -1], [0, -1, 0, -1]], ctrl[[0, 0, -1, -1], [0, -1, 0, -1]]
        )


def test_reduce_surface_elevated_returns_original():
    rng = np.random.default_rng(4)
    orig = rng.normal(size=(4, 3, 3))
    for fix in (True, False):
        new, bound = reduce_surface(elevate_surface(orig, 5, 7), 3, 2, fix_boundary=fix)
        assert bound < 1e-12
        np.testing.assert_allclose(new, orig, atol=1e-11)


def test_reduce_surface_boundaries_given_and_checked():
    rng = np.random.default_rng(5)
    ctrl = rng.normal(size=(7, 7, 3))
    new, _ = reduce_surface(ctrl, 4, 4)
    given_b = (new[0], new[-1], new[:, 0], new[:, -1])
    again, _ = reduce_surface(ctrl, 4, 4, boundaries=given_b)
    np.testing.assert_array_equal(again[0], new[0])
    np.testing.assert_array_equal(again[:, -1], new[:, -1])
    bad = (new[0] + 1.0, new[-1], new[:, 0], new[:, -1])
    with pytest.raises(ValueError, match="corners"):
        reduce_surface(ctrl, 4, 4, boundaries=bad)
    with pytest.raises(ValueError, match="boundary curve"):
        reduce_surface(ctrl, 4, 4, boundary_tol=1e-9)
    # an exactly representable boundary passes the boundary_tol check
    low = elevate_surface(rng.normal(size=(5, 5, 3)), 2, 2)
    _, b = reduce_surface(low, 4, 4, boundary_tol=1e-9)
    assert b < 1e-12
