"""Bernstein basics: binomials, basis, products, power-basis conversion."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.core.bernstein import (
    basis,
    basis_and_lower,
    binom,
    binom_table,
    from_power,
    product,
    product2,
    scalar_fn,
    to_power,
)
from watertight_cli.core.bezier import curve_eval, surface_eval

from .helpers import seeds

SETTINGS = settings(max_examples=40, deadline=None)


def test_binom_table_exact():
    tb = binom_table(30)
    for n in range(31):
        for k in range(31):
            assert tb[n, k] == (math.comb(n, k) if k <= n else 0)
    assert binom(5, 2) == 10.0 and binom(5, 7) == 0.0 and binom(5, -1) == 0.0
    assert binom_table(30) is tb  # cached
    assert not tb.flags.writeable


@SETTINGS
@given(seeds, st.integers(0, 25))
def test_basis_partition_of_unity_and_closed_form(seed, n):
    t = np.random.default_rng(seed).random(50)
    b = basis(n, t)
    assert b.shape == (50, n + 1)
    np.testing.assert_allclose(b.sum(axis=1), 1.0, rtol=0, atol=1e-14)
    k = np.arange(n + 1)
    closed = binom_table(n)[n] * t[:, None] ** k * (1 - t[:, None]) ** (n - k)
    np.testing.assert_allclose(b, closed, rtol=1e-12, atol=1e-15)


@SETTINGS
@given(seeds, st.integers(1, 25), st.integers(1, 60))
def test_basis_and_lower_are_the_two_bases_to_the_bit(seed, n, count):
    """The derivative helper shares the powers of t and gives the same bits as two calls, for short
    inputs too (a shared table of the powers of 1 - t, read reversed, differed in the last bit for
    a single parameter at degrees 23 to 26) and past the ends."""
    rng = np.random.default_rng(seed)
    t = np.concatenate([[0.0, 1.0, -0.01, 1.01], rng.random(count)])[-count:]
    b, lower = basis_and_lower(n, t)
    assert np.array_equal(b, basis(n, t)) and np.array_equal(lower, basis(n - 1, t))


@SETTINGS
@given(seeds, st.integers(0, 25))
def test_scalar_fn_matches_basis(seed, n):
    """The one-float evaluator agrees with the basis to rounding, and exactly at the ends."""
    rng = np.random.default_rng(seed)
    c = rng.normal(size=n + 1) * 10.0 ** rng.integers(-3, 4)
    f = scalar_fn(c)
    t = np.concatenate([[0.0, 0.5, 1.0], rng.random(40)])
    got = np.array([f(x) for x in t])
    np.testing.assert_allclose(got, basis(n, t) @ c, rtol=0, atol=1e-13 * np.abs(c).max())
    assert f(0.0) == c[0] and f(1.0) == c[-1]


@SETTINGS
@given(seeds, st.integers(0, 12), st.integers(0, 12), st.sampled_from([(), (3,)]), st.booleans())
def test_product_univariate(seed, p, q, tail, b_scalar):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(p + 1,) + tail)
    b = rng.normal(size=(q + 1,)) if b_scalar else rng.normal(size=(q + 1,) + tail)
    c = product(a, b)
    assert c.shape[0] == p + q + 1
    t = rng.random(40)
    fa, fb = curve_eval(a, t), curve_eval(b, t)
    if fb.ndim < fa.ndim:
        fb = fb[:, None]
    np.testing.assert_allclose(curve_eval(c, t), fa * fb, rtol=0, atol=1e-12 * (1 + np.abs(fa * fb).max()))


def test_product_axis():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 4))
    b = rng.normal(size=(3, 2))
    c = product(a, b, axis=1)
    assert c.shape == (3, 5)
    for r in range(3):
        np.testing.assert_allclose(c[r], product(a[r], b[r]), atol=1e-15)


@SETTINGS
@given(seeds, st.integers(0, 6), st.integers(0, 6), st.integers(0, 6), st.integers(0, 6))
def test_product2(seed, p, q, r, s):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(p + 1, q + 1, 3))
    b = rng.normal(size=(r + 1, s + 1))
    c = product2(a, b)
    assert c.shape == (p + r + 1, q + s + 1, 3)
    u, v = rng.random(30), rng.random(30)
    ref = surface_eval(a, u, v) * surface_eval(b, u, v)[:, None]
    np.testing.assert_allclose(surface_eval(c, u, v), ref, atol=1e-12 * (1 + np.abs(ref).max()))


@SETTINGS
@given(seeds, st.integers(0, 10))
def test_power_roundtrip(seed, n):
    rng = np.random.default_rng(seed)
    c = rng.normal(size=(n + 1, 2))
    a = to_power(c)
    t = rng.random(20)
    np.testing.assert_allclose(np.polynomial.polynomial.polyval(t, a).T, curve_eval(c, t), atol=1e-9)
    np.testing.assert_allclose(from_power(a), c, atol=1e-9)
