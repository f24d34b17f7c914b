"""Exact composition: the composed patch at (s, t) equals the surface at phi(s, t)."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from watertight_cli.core.bezier import (
    curve_eval,
    homogenize,
    rational_surface_eval,
    surface_eval,
)
from watertight_cli.core.compose import (
    compose,
    compose_batch,
    composed_bidegree,
    identity_map,
    paper_map,
    ruled_map,
)

from .helpers import seeds

SETTINGS = settings(max_examples=60, deadline=None)
REL = 1e-11


def random_surface(rng, m, n, rational):
    pts = rng.normal(size=(m + 1, n + 1, 3))
    if rational:
        return homogenize(pts, rng.uniform(0.3, 3.0, (m + 1, n + 1)))
    return pts


def check_composition(ctrl, U, V, rational, rng, k=200):
    out = compose(ctrl, U, V)
    m, n = ctrl.shape[0] - 1, ctrl.shape[1] - 1
    ds, dt = composed_bidegree(m, n, (U.shape[0] - 1, U.shape[1] - 1), (V.shape[0] - 1, V.shape[1] - 1))
    assert out.shape == (ds + 1, dt + 1, ctrl.shape[2])
    s = np.concatenate([rng.random(k), [0, 0, 1, 1]])
    t = np.concatenate([rng.random(k), [0, 1, 0, 1]])
    u = surface_eval(U[:, :, None], s, t)[:, 0]
    v = surface_eval(V[:, :, None], s, t)[:, 0]
    ev = rational_surface_eval if rational else surface_eval
    ref = ev(ctrl, u, v)
    got = ev(out, s, t)
    err = np.abs(got - ref).max() / max(1.0, np.abs(ref).max())
    assert err < REL, (err, out.shape)
    return out


@SETTINGS
@given(
    seeds,
    st.integers(0, 6),
    st.integers(0, 6),
    st.integers(0, 5),
    st.integers(0, 5),
    st.integers(0, 5),
    st.integers(0, 5),
    st.booleans(),
)
def test_compose_general_maps(seed, m, n, a, b, c, e, rational):
    ds, dt = composed_bidegree(m, n, (a, b), (c, e))
    assume(ds <= 25 and dt <= 25)
    rng = np.random.default_rng(seed)
    ctrl = random_surface(rng, m, n, rational)
    U = rng.random((a + 1, b + 1))
    V = rng.random((c + 1, e + 1))
    check_composition(ctrl, U, V, rational, rng)


@SETTINGS
@given(seeds, st.integers(1, 4), st.integers(1, 4), st.integers(1, 4), st.integers(0, 3), st.booleans())
def test_compose_ruled_map(seed, m, n, p, po, rational):
    assume((m + n) * max(p, po) <= 25)
    rng = np.random.default_rng(seed)
    ctrl = random_surface(rng, m, n, rational)
    T = rng.random((p + 1, 2))
    O = rng.random((po + 1, 2))
    U, V = ruled_map(O, T)
    assert U.shape == V.shape == (2, max(p, po) + 1)
    out = check_composition(ctrl, U, V, rational, rng)
    assert out.shape[:2] == ((m + n) + 1, (m + n) * max(p, po) + 1)
    # the s = 1 side of the patch is S(T(t)), the s = 0 side S(O(t))
    t = rng.random(50)
    tt = curve_eval(T, t)
    ev = rational_surface_eval if rational else surface_eval
    ref = ev(ctrl, tt[:, 0], tt[:, 1])
    side = ev(out, np.ones_like(t), t)
    assert np.abs(side - ref).max() / max(1, np.abs(ref).max()) < REL


@SETTINGS
@given(
    seeds,
    st.integers(1, 5),
    st.integers(1, 5),
    st.integers(1, 6),
    st.floats(0, 1),
    st.booleans(),
    st.booleans(),
    st.booleans(),
)
def test_compose_paper_map(seed, m, n, p, u0, swap_uv, swap_st, rational):
    rng = np.random.default_rng(seed)
    f = rng.random(p + 1)
    t0, t1 = np.sort(rng.random(2))
    U, V = paper_map(f, u0=u0, t_range=(t0, t1), swap_uv=swap_uv, swap_st=swap_st)
    ds, dt = composed_bidegree(m, n, (U.shape[0] - 1, U.shape[1] - 1), (V.shape[0] - 1, V.shape[1] - 1))
    assume(max(ds, dt) <= 25)
    ctrl = random_surface(rng, m, n, rational)
    out = check_composition(ctrl, U, V, rational, rng)
    if not swap_uv and not swap_st:
        assert out.shape[:2] == (m + 1, m * p + n + 1)  # the paper's m x (m p + n)


def test_paper_map_is_papers_map():
    f = np.array([0.5, 0.9, 0.7])
    U, V = paper_map(f)
    s, t = np.random.default_rng(0).random((2, 20))
    np.testing.assert_allclose(surface_eval(U[:, :, None], s, t)[:, 0], s * curve_eval(f, t), atol=1e-15)
    np.testing.assert_allclose(surface_eval(V[:, :, None], s, t)[:, 0], t, atol=1e-15)


def test_compose_identity_is_identity():
    rng = np.random.default_rng(2)
    ctrl = random_surface(rng, 3, 4, True)
    U, V = identity_map()
    np.testing.assert_allclose(compose(ctrl, U, V), ctrl, rtol=0, atol=1e-14)


def test_compose_degree_25_bicubic_octic_pcurve():
    """The realistic worst case: bicubic S with a degree-8 ruled map would be 6 x 48 (too high);
    a degree-4 trimming piece gives 6 x 24."""
    rng = np.random.default_rng(7)
    ctrl = random_surface(rng, 3, 3, True)
    U, V = ruled_map(np.array([[0.0, 0.0], [0.0, 1.0]]), rng.random((5, 2)))
    check_composition(ctrl, U, V, True, rng)
    with pytest.raises(ValueError, match="budget"):
        compose(ctrl, *ruled_map(rng.random((2, 2)), rng.random((9, 2))), max_degree=25)


@settings(max_examples=15, deadline=None)
@given(seeds, st.integers(1, 3), st.integers(1, 3), st.integers(1, 4), st.booleans())
def test_compose_batch_equals_single(seed, m, n, p, shared_v):
    rng = np.random.default_rng(seed)
    N = 7
    ctrls = rng.normal(size=(N, m + 1, n + 1, 4))
    Us = rng.random((N, 2, p + 1))
    Vs = rng.random((2, p + 1)) if shared_v else rng.random((N, 2, p + 1))
    out = compose_batch(ctrls, Us, Vs)
    for i in range(N):
        ref = compose(ctrls[i], Us[i], Vs if shared_v else Vs[i])
        np.testing.assert_allclose(out[i], ref, rtol=0, atol=1e-13 * np.abs(ref).max())


def test_compose_batch_different_u_v_shapes():
    rng = np.random.default_rng(3)
    ctrls = rng.normal(size=(5, 4, 3, 3))
    Us, Vs = rng.random((5, 2, 3)), rng.random((5, 1, 2))
    out = compose_batch(ctrls, Us, Vs)
    for i in range(5):
        np.testing.assert_allclose(out[i], compose(ctrls[i], Us[i], Vs[i]), atol=1e-13)


def test_compose_rejects_bad_shapes():
    with pytest.raises(ValueError):
        compose(np.zeros((4, 4, 3)), np.zeros((2,)), np.zeros((2, 2)))
    with pytest.raises(ValueError):
        compose_batch(np.zeros((3, 4, 4, 3)), np.zeros((2, 2, 2)), np.zeros((2, 2)))
    with pytest.raises(ValueError):
        ruled_map(np.zeros((3, 3)), np.zeros((3, 2)))
