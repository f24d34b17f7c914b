"""Same-parameter repair (``sameparam``) and the knot-following gap samples (``gaps.track_params``).

The synthetic face is the plane z = 0 over [0, 1]^2. The edge curve runs along the parabola
v = u^2 as C(t) = (t, t^2, 0); the pcurves trace the same parabola (or one beside it) at other speeds.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.core.bspline import insert_knot
from watertight_cli.gaps import track_params
from watertight_cli.model import BSplineCurve, BSplineSurface, Coedge, Edge, Face, Loop, Model
from watertight_cli.sameparam import retime
from watertight_cli.tolerances import Tolerances

TOL = Tolerances()


def _bezier_through(f, degree: int) -> BSplineCurve:
    """The degree-``degree`` Bezier curve equal to the polynomial curve f on [0, 1]."""
    from math import comb

    x = np.linspace(0, 1, degree + 1)
    B = np.array([[comb(degree, i) * xi ** i * (1 - xi) ** (degree - i) for i in range(degree + 1)]
                  for xi in x])
    poles = np.linalg.solve(B, f(x))
    return BSplineCurve(degree, np.r_[[0.0] * (degree + 1), [1.0] * (degree + 1)], poles)


def _model(pcurve: BSplineCurve, curve: BSplineCurve | None = None) -> Model:
    """The plane z = 0 with one edge (default: C(t) = (t, t^2, 0), knots crowding near t = 0 as in
    the files where this happens) and one coedge with ``pcurve``."""
    plane = BSplineSurface(1, 1, np.array([0, 0, 1, 1.0]), np.array([0, 0, 1, 1.0]),
                           np.array([[[0, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0]]], dtype=float))
    if curve is None:
        c = _bezier_through(lambda t: np.stack([t, t * t, 0 * t], -1), 2)
        knots, poles = c.knots, c.poles
        for u in (0.001, 0.003, 0.01, 0.03, 0.1, 0.3):
            knots, poles = insert_knot(knots, 2, poles, u)
        curve = BSplineCurve(2, knots, poles)
    edge = Edge(0, curve, 0.0, 1.0, 1e-7, (0, 1), (0,), False, False)
    face = Face(0, plane, "Plane", False, (Loop((Coedge(0, False, pcurve, 0.0, 1.0),), True),),
                (0.0, 1.0, 0.0, 1.0))
    return Model("synthetic", [face], [edge], np.array([[0, 0, 0], [1, 1, 0.0]]), np.sqrt(2.0), 0, 1)


INNER = [0.0025, 0.005, 0.01, 0.02, 0.03, 0.3, 0.6]  # knots crowding at the start, as in the files


def test_a_pcurve_at_another_speed_is_retimed_exactly_onto_the_edge():
    """C(t) = (t, t/2, 0) on the line; pc = (g, g/2) with g(t) = t + a lag over the first 3 %."""
    flat = np.r_[[0.0] * 4, INNER, [1.0] * 4]
    grev = np.array([flat[i + 1:i + 4].mean() for i in range(len(flat) - 4)])
    g = grev + np.r_[0.0, -0.0004, -0.0012, -0.0030, -0.0040, [0.0] * (len(grev) - 5)]
    pc = BSplineCurve(3, flat, np.stack([g, 0.5 * g], -1))
    knots, poles = np.array([0, 0, 1, 1.0]), np.array([[0, 0, 0], [1, 0.5, 0]])
    for u in INNER:
        knots, poles = insert_knot(knots, 1, poles, u)
    m = _model(pc, BSplineCurve(1, knots, poles))
    t = np.linspace(0, 1, 20001)
    c = m.edges[0].curve.evaluate(t)
    before = np.linalg.norm(pc.evaluate(t) - c[:, :2], axis=1).max()
    assert before > 2e-3  # the set-up: S(pc(t)) lags C(t) near the start

    done = retime(m, TOL)

    assert len(done) == 1
    new = m.faces[0].loops[0].coedges[0].pcurve
    uv = new.evaluate(t)
    # the trim does not move: the new pcurve traces the same segment, to rounding
    assert np.abs(uv[:, 1] - 0.5 * uv[:, 0]).max() < 1e-15
    assert np.abs(uv[[0, -1]] - pc.evaluate(np.array([0.0, 1.0]))).max() < 1e-15
    # and runs much nearer to C
    after = np.linalg.norm(m.faces[0].surface.evaluate(uv) - c, axis=1).max()
    assert after < 0.2 * before and after <= 1.01 * done[0].after  # the report samples it
    assert done[0].trace_gap < 1e-12
    # one node per knot of C or of the old pcurve (each becomes a cut of the edge plan): no more
    assert len(np.unique(new.knots)) <= len(np.unique(knots)) + len(INNER)
    # same degree, no approximation recorded
    assert new.degree == pc.degree and m.faces[0].approximation == 0.0


def test_a_same_parameter_pcurve_is_left_alone():
    pc = _bezier_through(lambda s: np.stack([s, s * s], -1), 2)
    m = _model(pc)
    assert retime(m, TOL) == []
    assert m.faces[0].loops[0].coedges[0].pcurve is pc


def test_a_pcurve_beside_the_edge_is_a_gap_not_a_timing_and_is_left_alone():
    """The trace runs 0.05 beside C at C's own speed: re-timing cannot help, so nothing changes."""
    pc = _bezier_through(lambda s: np.stack([s, s * s + 0.05], -1), 2)
    m = _model(pc)
    assert retime(m, TOL) == []
    assert m.faces[0].loops[0].coedges[0].pcurve is pc


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=0, max_size=12), st.integers(3, 40), st.integers(1, 4))
def test_track_params_put_samples_in_every_knot_span(knots, uniform, per_span):
    a, b = 0.0, 1.0
    kv = np.sort(np.r_[[a] * 3, knots, [b] * 3])
    w = track_params(a, b, uniform, [kv], per_span)
    assert w[0] == a and w[-1] == b and np.all(np.diff(w) > 0)
    assert np.all(np.isin(np.linspace(a, b, uniform), w))
    u = np.unique(kv)
    for lo, hi in zip(u[:-1], u[1:], strict=True):
        if hi - lo < 1e-9:  # a span a few ulps wide has no room for samples
            continue
        inside = np.count_nonzero((w > lo) & (w < hi))
        assert inside >= per_span


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 25), st.integers(1, 25), st.booleans(), st.floats(-3.0, 3.0), st.floats(0.01, 5.0),
       st.integers(0, 2**32 - 1))
def test_bezier_sampling_of_the_read_back_matches_the_spline(p, q, rational, k0, width, seed):
    """The read-back's gap tracks evaluate one-span curves and Bezier patches by their Bernstein
    bases (``gaps._curve_at``, ``gaps._surface_at``); they agree with scipy's splines, past the
    ends too (pcurves run slightly outside their surface's domain)."""
    from watertight_cli.gaps import _curve_at, _surface_at

    rng = np.random.default_rng(seed)
    w = np.sort(np.r_[k0 - 0.01 * width, k0 + width * rng.random(30), k0 + 1.01 * width])
    weights = rng.uniform(0.5, 2.0, p + 1) if rational else None
    c = BSplineCurve(p, np.r_[[k0] * (p + 1), [k0 + width] * (p + 1)], rng.normal(size=(p + 1, 3)), weights)
    assert np.allclose(_curve_at(c, w), c.evaluate(w), rtol=0, atol=1e-12)
    kv = np.r_[[k0] * (q + 1), [k0 + width] * (q + 1)]
    sw = rng.uniform(0.5, 2.0, (p + 1, q + 1)) if rational else None
    s = BSplineSurface(p, q, c.knots, kv, rng.normal(size=(p + 1, q + 1, 3)), sw)
    uv = np.c_[w, w[::-1]]
    assert np.allclose(_surface_at(s, uv), s.evaluate(uv), rtol=0, atol=1e-12)


def test_slow_pcurve_fixture_is_measured_and_retimed(tmp_path):
    """The fixture's top face runs 0.13 behind its edge over the first 3 % (equal steps see nothing):
    the report's knot-span samples find it, and the conversion re-times the pcurve, so stage 2
    moves that face's boundary by a fraction of the mismatch (without re-timing: all of it)."""
    from watertight_cli.convert import convert_file
    from watertight_cli.gaps import max_gap
    from watertight_cli.inspect import inspect
    from watertight_cli.occ.extract import sample_tracks

    from .conftest import fixture_path

    path = str(fixture_path("slow_pcurve_box.step"))
    ins = inspect(path, TOL)
    dense = max(g.gap for g in ins.gaps)
    assert dense > 0.1
    assert max_gap(sample_tracks(ins.shape, TOL.gap_samples, per_span=0)) < 1e-9 * ins.model.diagonal

    rep = convert_file(path, str(tmp_path / "o.step"), TOL)
    rt = rep["retimed_pcurves"]
    assert rt["count"] == 1 and rt["faces_kept_as_read"] == 0
    assert rt["mismatch_before_max"] > 0.1 and rt["mismatch_after_max"] < 0.1 * rt["mismatch_before_max"]
    assert rep["substitution_move_max"] <= 0.25 * rt["mismatch_before_max"]
    assert all(rep["invariants"].values()), rep["invariants"]
