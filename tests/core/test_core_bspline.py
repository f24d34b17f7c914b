"""B-spline knot insertion and Bezier extraction against scipy's de Boor evaluation."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import BSpline

from watertight_cli.core.bezier import curve_eval, homogenize, rational_curve_eval, surface_eval_grid
from watertight_cli.core.bspline import (
    bspline_eval,
    find_span,
    insert_knot,
    merge_removable_spans,
    split_curve_at,
    surface_to_bezier,
    to_bezier,
)

from .helpers import rel_err, seeds

SETTINGS = settings(max_examples=40, deadline=None)
REL = 1e-12



def random_knots(rng, p, clamped=True):
    """Random knot vector of degree p with interior multiplicities 1..p, on a random range."""
    k = int(rng.integers(0, 6))
    a = rng.uniform(-5, 5)
    b = a + rng.uniform(0.5, 10)
    interior = np.sort(rng.uniform(a, b, k))
    mults = rng.integers(1, p + 1, k) if p > 0 else np.ones(k, int)
    inner = np.repeat(interior, mults)
    if clamped:
        return np.concatenate([np.full(p + 1, a), inner, np.full(p + 1, b)])
    # unclamped ends: p extra knots strictly outside [a, b] plus a and b once
    lo = a - np.sort(rng.uniform(0.1, 2, p))[::-1]
    hi = b + np.sort(rng.uniform(0.1, 2, p))
    return np.concatenate([lo, [a], inner, [b], hi])


def extracted_eval(breaks, segs, x, rational=False):
    """Evaluate extracted Bezier segments at global parameters x."""
    j = np.clip(np.searchsorted(breaks, x, side="right") - 1, 0, len(segs) - 1)
    out = np.empty((len(x), segs.shape[-1] - (1 if rational else 0)))
    for i in np.unique(j):
        sel = j == i
        loc = (x[sel] - breaks[i]) / (breaks[i + 1] - breaks[i])
        out[sel] = rational_curve_eval(segs[i], loc) if rational else curve_eval(segs[i], loc)
    return out


@SETTINGS
@given(seeds, st.integers(1, 7), st.booleans(), st.booleans())
def test_to_bezier_matches_scipy(seed, p, clamped, rational):
    rng = np.random.default_rng(seed)
    knots = random_knots(rng, p, clamped)
    nctrl = len(knots) - p - 1
    ctrl = rng.normal(size=(nctrl, 3))
    if rational:
        ctrl = homogenize(ctrl, rng.uniform(0.3, 3, nctrl))
    breaks, segs = to_bezier(knots, p, ctrl)
    assert segs.shape == (len(breaks) - 1, p + 1, ctrl.shape[1])
    assert breaks[0] == knots[p] and breaks[-1] == knots[nctrl]
    x = np.concatenate([rng.uniform(breaks[0], breaks[-1], 200), breaks])
    ref = BSpline(knots, ctrl, p)(x)
    if rational:
        ref = ref[:, :-1] / ref[:, -1:]
    assert rel_err(extracted_eval(breaks, segs, x, rational), ref) < REL
    ours = bspline_eval(knots, p, ctrl, x)
    assert rel_err(ours[:, :-1] / ours[:, -1:] if rational else ours, ref) < REL


@SETTINGS
@given(seeds, st.integers(1, 6))
def test_insert_knot_keeps_curve(seed, p):
    rng = np.random.default_rng(seed)
    knots = random_knots(rng, p)
    ctrl = rng.normal(size=(len(knots) - p - 1, 2))
    u = rng.uniform(knots[0], knots[-1])
    if rng.random() < 0.3 and len(np.unique(knots)) > 2:  # sometimes an existing interior knot
        u = float(np.unique(knots)[1])
    s = int(np.count_nonzero(knots == u))
    r = int(rng.integers(0, p - s + 1)) if s < p else 0
    k2, c2 = insert_knot(knots, p, ctrl, u, r)
    assert len(k2) == len(knots) + r and len(c2) == len(ctrl) + r
    x = rng.uniform(knots[0], knots[-1], 100)
    assert rel_err(BSpline(k2, c2, p)(x), BSpline(knots, ctrl, p)(x)) < REL
    if s < p:
        with pytest.raises(ValueError):
            insert_knot(knots, p, ctrl, u, p - s + 1)


def test_find_span():
    knots = np.array([0, 0, 0, 1, 2, 2, 3, 3, 3], float)
    p = 2
    np.testing.assert_array_equal(
        find_span(knots, p, np.array([0, 0.5, 1, 1.5, 2, 2.5, 3])), [2, 2, 3, 3, 5, 5, 5]
    )
    assert find_span(knots, p, 3.0) == 5


def test_to_bezier_rejects_bad_input():
    with pytest.raises(ValueError):
        to_bezier([0, 0, 1, 1], 1, np.zeros((3, 2)))  # wrong length
    with pytest.raises(ValueError):
        to_bezier([0, 0, 1, 0.5, 1, 1], 2, np.zeros((3, 2)))  # decreasing


@SETTINGS
@given(seeds, st.integers(1, 4), st.integers(1, 4), st.booleans())
def test_surface_to_bezier_matches_scipy(seed, p, q, clamped):
    rng = np.random.default_rng(seed)
    uk, vk = random_knots(rng, p, clamped), random_knots(rng, q, clamped)
    nu, nv = len(uk) - p - 1, len(vk) - q - 1
    ctrl = homogenize(rng.normal(size=(nu, nv, 3)), rng.uniform(0.3, 3, (nu, nv)))
    ub, vb, patches = surface_to_bezier(uk, vk, p, q, ctrl)
    assert patches.shape == (len(ub) - 1, len(vb) - 1, p + 1, q + 1, 4)
    s = rng.uniform(ub[0], ub[-1], 9)
    t = rng.uniform(vb[0], vb[-1], 11)
    tmp = BSpline(uk, ctrl, p)(s)  # (9, nv, 4)
    ref = BSpline(vk, np.moveaxis(tmp, 1, 0), q)(t)  # (11, 9, 4)
    ref = np.moveaxis(ref, 0, 1)
    ref = ref[..., :3] / ref[..., 3:]
    i = np.clip(np.searchsorted(ub, s, side="right") - 1, 0, len(ub) - 2)
    j = np.clip(np.searchsorted(vb, t, side="right") - 1, 0, len(vb) - 2)
    for a in range(len(s)):
        for b in range(len(t)):
            pa = patches[i[a], j[b]]
            ls = (s[a] - ub[i[a]]) / (ub[i[a] + 1] - ub[i[a]])
            lt = (t[b] - vb[j[b]]) / (vb[j[b] + 1] - vb[j[b]])
            h = surface_eval_grid(pa, [ls], [lt])[0, 0]
            np.testing.assert_allclose(h[:3] / h[3], ref[a, b], rtol=0, atol=REL * max(1, np.abs(ref).max()))


@SETTINGS
@given(seeds, st.integers(1, 6))
def test_split_curve_at(seed, p):
    rng = np.random.default_rng(seed)
    knots = random_knots(rng, p)
    ctrl = rng.normal(size=(len(knots) - p - 1, 3))
    a, b = knots[p], knots[-p - 1]
    params = rng.uniform(a, b, int(rng.integers(0, 5)))
    breaks, segs = split_curve_at(knots, p, ctrl, params)
    assert set(np.round(params, 14)) <= set(np.round(breaks, 14))
    assert len(segs) == len(breaks) - 1
    x = np.concatenate([rng.uniform(a, b, 200), breaks])
    assert rel_err(extracted_eval(breaks, segs, x), BSpline(knots, ctrl, p)(x)) < 1e-11
    with pytest.raises(ValueError):
        split_curve_at(knots, p, ctrl, [b + 1.0])


@SETTINGS
@given(seeds, st.integers(1, 6), st.booleans(), st.integers(1, 4))
def test_merge_removable_spans_drops_inserted_knots_only(seed, p, clamped, extra):
    """Knots inserted into a spline (removable by construction) go; its own breaks stay, at full
    multiplicity, and the geometry is unchanged."""
    rng = np.random.default_rng(seed)
    knots = random_knots(rng, p, clamped)
    ctrl = rng.normal(size=(len(knots) - p - 1, 3))
    a, b = knots[p], knots[len(knots) - p - 1]
    own = set(np.unique(knots[(knots > a) & (knots < b)]).tolist())
    k2, c2 = knots, ctrl
    added = set()
    for u in rng.uniform(a, b, extra):
        if min([abs(u - x) for x in own | {a, b}]) < 1e-3 * (b - a):
            continue
        k2, c2 = insert_knot(k2, p, c2, float(u), int(rng.integers(1, p + 1)))
        added.add(float(u))
    out = merge_removable_spans(k2, p, c2, 1e-9)
    if not added:  # random control points: the spline's own knots are breaks
        assert out is None
        return
    assert out is not None
    kn, cp = out
    inner = set(np.unique(kn[(kn > a) & (kn < b)]).tolist())
    assert not inner & added
    assert kn[0] == a and kn[-1] == b
    x = np.concatenate([rng.uniform(a, b, 200), [a, b]])
    assert rel_err(BSpline(kn, cp, p)(x), BSpline(knots, ctrl, p)(x)) < 1e-9


def test_merge_removable_spans_keeps_a_real_break():
    """A kink (a knot of full multiplicity with a corner) stays; a C1 join of two different cubics
    stays too, though its first derivative is continuous."""
    p = 3
    knots = np.array([0, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2], float)
    ctrl = np.array([[0, 0], [1, 1], [2, 1], [3, 0], [4, 1], [5, 1], [6, 0]], float)
    assert merge_removable_spans(knots, p, ctrl, 1e-9) is None
    c1 = ctrl.copy()
    c1[4] = 2 * c1[3] - c1[2]  # C1 at u = 1, still two polynomials
    assert merge_removable_spans(knots, p, c1, 1e-9) is None
    # the same cubic twice: one polynomial across u = 1
    k1, cubic = np.array([0, 0, 0, 0, 2, 2, 2, 2], float), np.array([[0, 0], [1, 3], [3, -1], [4, 2]], float)
    k2, c2 = insert_knot(k1, p, cubic, 1.0, 3)
    kn, cp = merge_removable_spans(k2, p, c2, 1e-12)
    assert np.allclose(kn, k1) and np.allclose(cp, cubic, atol=1e-12)
