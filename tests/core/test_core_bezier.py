"""Bezier curves and surfaces: evaluation, subdivision and elevation reproduce the parent."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.core.bezier import (
    curve_derivative,
    curve_eval,
    curve_segment,
    curve_split,
    dehomogenize,
    elevate_curve,
    elevate_surface,
    homogenize,
    rational_curve_eval,
    rational_surface_eval,
    rational_surface_eval_grid,
    surface_derivatives,
    surface_eval,
    surface_eval_grid,
    surface_split_u,
    surface_split_v,
    surface_subbox,
)

from .helpers import rel_err, seeds

SETTINGS = settings(max_examples=40, deadline=None)
REL = 1e-12



def random_curve(rng, n, d=3, rational=False):
    pts = rng.normal(size=(n + 1, d))
    if rational:
        return homogenize(pts, rng.uniform(0.3, 3.0, n + 1))
    return pts


def random_surface(rng, m, n, d=3, rational=False):
    pts = rng.normal(size=(m + 1, n + 1, d))
    if rational:
        return homogenize(pts, rng.uniform(0.3, 3.0, (m + 1, n + 1)))
    return pts


def ceval(c, t, rational):
    return rational_curve_eval(c, t) if rational else curve_eval(c, t)


def seval(c, s, t, rational):
    return rational_surface_eval(c, s, t) if rational else surface_eval(c, s, t)


def test_homogenize_roundtrip():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(5, 3))
    w = rng.uniform(0.5, 2, 5)
    h = homogenize(p, w)
    assert h.shape == (5, 4)
    np.testing.assert_allclose(h[:, 3], w)
    np.testing.assert_allclose(dehomogenize(h), p, rtol=1e-15)
    with pytest.raises(ValueError):
        homogenize(p, w[:3])


def test_curve_eval_de_casteljau_and_ends():
    rng = np.random.default_rng(3)
    c = rng.normal(size=(6, 2))
    t = rng.random(7)
    # de Casteljau reference
    ref = []
    for tt in t:
        w = c.copy()
        while len(w) > 1:
            w = (1 - tt) * w[:-1] + tt * w[1:]
        ref.append(w[0])
    np.testing.assert_allclose(curve_eval(c, t), np.array(ref), atol=1e-14)
    np.testing.assert_array_equal(curve_eval(c, [0.0, 1.0]), c[[0, -1]])


@SETTINGS
@given(seeds, st.integers(1, 15))
def test_curve_derivative_matches_finite_difference(seed, n):
    rng = np.random.default_rng(seed)
    c = rng.normal(size=(n + 1, 3))
    t = rng.uniform(0.05, 0.95, 10)
    h = 1e-6
    fd = (curve_eval(c, t + h) - curve_eval(c, t - h)) / (2 * h)
    np.testing.assert_allclose(curve_eval(curve_derivative(c), t), fd, atol=1e-5 * (1 + np.abs(fd).max()))


@SETTINGS
@given(seeds, st.integers(0, 20), st.floats(0.0, 1.0), st.booleans())
def test_curve_split_reproduces_parent(seed, n, tsplit, rational):
    rng = np.random.default_rng(seed)
    c = random_curve(rng, n, rational=rational)
    left, right = curve_split(c, tsplit)
    np.testing.assert_array_equal(left[-1], right[0])
    np.testing.assert_array_equal(left[0], c[0])
    np.testing.assert_array_equal(right[-1], c[-1])
    x = np.linspace(0, 1, 41)
    ref_l = ceval(c, tsplit * x, rational)
    ref_r = ceval(c, tsplit + (1 - tsplit) * x, rational)
    assert rel_err(ceval(left, x, rational), ref_l) < REL
    assert rel_err(ceval(right, x, rational), ref_r) < REL


@SETTINGS
@given(seeds, st.integers(0, 20), st.floats(-0.2, 1.2), st.floats(-0.2, 1.2), st.booleans())
def test_curve_segment_any_interval_including_reversed(seed, n, a, b, rational):
    rng = np.random.default_rng(seed)
    c = random_curve(rng, n, rational=rational)
    seg = curve_segment(c, a, b)
    x = np.linspace(0, 1, 41)
    ref = ceval(c, (1 - x) * a + x * b, rational)
    # extrapolation outside [0, 1] amplifies rounding by at most ~ (1 + 2*0.2)^n
    tol = REL * (1.4**n if (min(a, b) < 0 or max(a, b) > 1) else 1.0)
    assert rel_err(ceval(seg, x, rational), ref) < tol


@SETTINGS
@given(seeds, st.integers(0, 15), st.integers(0, 12), st.booleans())
def test_elevate_curve_exact(seed, n, r, rational):
    rng = np.random.default_rng(seed)
    c = random_curve(rng, n, rational=rational)
    e = elevate_curve(c, r)
    assert e.shape[0] == n + r + 1
    np.testing.assert_array_equal(e[[0, -1]], c[[0, -1]])
    x = rng.random(50)
    assert rel_err(ceval(e, x, rational), ceval(c, x, rational)) < REL
    # r steps at once == r single steps
    step = c
    for _ in range(r):
        step = elevate_curve(step, 1)
    assert rel_err(step, e) < 1e-13


@SETTINGS
@given(seeds, st.integers(0, 8), st.integers(0, 8), st.floats(0, 1), st.floats(0, 1), st.booleans())
def test_surface_split_reproduces_parent(seed, m, n, su, sv, rational):
    rng = np.random.default_rng(seed)
    c = random_surface(rng, m, n, rational=rational)
    s, t = rng.random(60), rng.random(60)
    lo, hi = surface_split_u(c, su)
    assert rel_err(seval(lo, s, t, rational), seval(c, su * s, t, rational)) < REL
    assert rel_err(seval(hi, s, t, rational), seval(c, su + (1 - su) * s, t, rational)) < REL
    lo, hi = surface_split_v(c, sv)
    assert rel_err(seval(lo, s, t, rational), seval(c, s, sv * t, rational)) < REL
    assert rel_err(seval(hi, s, t, rational), seval(c, s, sv + (1 - sv) * t, rational)) < REL


@SETTINGS
@given(seeds, st.integers(0, 8), st.integers(0, 8), st.booleans())
def test_surface_subbox(seed, m, n, rational):
    rng = np.random.default_rng(seed)
    c = random_surface(rng, m, n, rational=rational)
    s0, s1, t0, t1 = rng.random(4)
    sub = surface_subbox(c, s0, s1, t0, t1)
    s, t = rng.random(60), rng.random(60)
    ref = seval(c, (1 - s) * s0 + s * s1, (1 - t) * t0 + t * t1, rational)
    assert rel_err(seval(sub, s, t, rational), ref) < REL


@SETTINGS
@given(seeds, st.integers(0, 8), st.integers(0, 8), st.integers(0, 6), st.integers(0, 6), st.booleans())
def test_elevate_surface_exact(seed, m, n, ru, rv, rational):
    rng = np.random.default_rng(seed)
    c = random_surface(rng, m, n, rational=rational)
    e = elevate_surface(c, ru, rv)
    assert e.shape[:2] == (m + ru + 1, n + rv + 1)
    s, t = rng.random(60), rng.random(60)
    assert rel_err(seval(e, s, t, rational), seval(c, s, t, rational)) < REL


def test_surface_eval_grid_and_pointwise_agree():
    rng = np.random.default_rng(5)
    c = random_surface(rng, 3, 5, d=3, rational=True)
    s, t = rng.random(7), rng.random(9)
    g = surface_eval_grid(c, s, t)
    assert g.shape == (7, 9, 4)
    ss, tt = np.meshgrid(s, t, indexing="ij")
    np.testing.assert_allclose(g.reshape(-1, 4), surface_eval(c, ss.ravel(), tt.ravel()), atol=1e-14)
    np.testing.assert_allclose(rational_surface_eval_grid(c, s, t), dehomogenize(g), rtol=1e-15)
    with pytest.raises(ValueError):
        surface_eval(c, s, t)


def test_surface_derivatives():
    rng = np.random.default_rng(6)
    c = random_surface(rng, 4, 3)
    du, dv = surface_derivatives(c)
    assert du.shape == (4, 4, 3) and dv.shape == (5, 3, 3)
    s, t = rng.uniform(0.1, 0.9, 10), rng.uniform(0.1, 0.9, 10)
    h = 1e-6
    fu = (surface_eval(c, s + h, t) - surface_eval(c, s - h, t)) / (2 * h)
    fv = (surface_eval(c, s, t + h) - surface_eval(c, s, t - h)) / (2 * h)
    np.testing.assert_allclose(surface_eval(du, s, t), fu, atol=1e-6)
    np.testing.assert_allclose(surface_eval(dv, s, t), fv, atol=1e-6)


def test_surface_volume_of_a_closed_set_of_patches():
    """Six bilinear faces of a box, and a rational octant sphere's eight patches, enclose their
    known volumes; elevating a patch or moving the origin changes nothing."""
    from watertight_cli.core.bezier import elevate_surface, surface_volume

    lo, hi = np.array([-1.0, 0.5, 2.0]), np.array([2.0, 3.0, 2.75])
    c = lambda i, j, k: np.where([i, j, k], hi, lo)  # noqa: E731
    faces = [  # inward (s, t) sense, P_s x P_t pointing in; transposed below to point out
        [[c(0, 0, 0), c(0, 1, 0)], [c(1, 0, 0), c(1, 1, 0)]],
        [[c(0, 0, 1), c(1, 0, 1)], [c(0, 1, 1), c(1, 1, 1)]],
        [[c(0, 0, 0), c(0, 0, 1)], [c(0, 1, 0), c(0, 1, 1)]],
        [[c(1, 0, 0), c(1, 1, 0)], [c(1, 0, 1), c(1, 1, 1)]],
        [[c(0, 0, 0), c(1, 0, 0)], [c(0, 0, 1), c(1, 0, 1)]],
        [[c(0, 1, 0), c(0, 1, 1)], [c(1, 1, 0), c(1, 1, 1)]],
    ]
    nets = [np.array(f, float).transpose(1, 0, 2) for f in faces]
    nets[1] = elevate_surface(nets[1], 3, 2)
    assert sum(surface_volume(n) for n in nets) == pytest.approx(np.prod(hi - lo), rel=1e-13)

    # sphere octant x, y, z >= 0 as a rational biquadratic patch with one collapsed side (a pole)
    r2 = np.sqrt(0.5)
    arc = np.array([[1, 0, 0, 1], [r2, r2, 0, r2], [0, 1, 0, 1]])  # quarter circle, homogeneous
    prof = np.array([[1, 0, 1], [r2, r2, r2], [0, 1, 1]])  # (cos, sin, weight) in the meridian
    H = np.zeros((3, 3, 4))
    for i in range(3):
        for j in range(3):
            x, y = arc[i, :2] / arc[i, 3]
            cz, sz, wz = prof[j]
            w = arc[i, 3] * wz
            H[i, j] = [x * cz / wz * w, y * cz / wz * w, sz / wz * w, w]
    v = surface_volume(H, rational=True)
    assert abs(v) == pytest.approx(np.pi / 6.0, rel=1e-9)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 6), st.integers(0, 6), st.booleans()), min_size=1, max_size=12),
       st.integers(0, 2**31 - 1))
def test_surface_volumes_of_mixed_nets_are_each_nets_volume(kinds, seed):
    """The batched volumes (grouped by bidegree and kind) come back in the order given, each the
    same as that net's volume alone, for polynomial and rational nets of mixed bidegrees."""
    from watertight_cli.core.bezier import surface_volume, surface_volumes

    rng = np.random.default_rng(seed)
    nets = []
    for m, n, rational in kinds:
        c = rng.standard_normal((m + 1, n + 1, 3))
        if rational:
            c = np.concatenate([c, rng.uniform(0.5, 2.0, (m + 1, n + 1, 1))], axis=-1)
        nets.append((c, rational))
    got = surface_volumes(nets)
    alone = np.array([surface_volume(c, r) for c, r in nets])
    assert got.shape == (len(nets),)
    np.testing.assert_allclose(got, alone, rtol=1e-12, atol=1e-12)
