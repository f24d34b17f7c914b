"""Stage 1 (untrim): the numeric pieces on small synthetic cases, and every fixture through
read -> untrim -> verify, checked against invariants I1 (Bezier on [0,1]^2), I4 (exact where no
approximation was needed, else within the reported bound) and I5 (degrees, no folds)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.tolerances import Tolerances
from watertight_cli.untrim import (
    Patch,
    Side,
    _cells,
    _close_loops,
    _FaceContext,
    _own_parameter,
    _reduce_side,
    cell_map,
    patch_points,
    untrim,
)

from .conftest import corpus_path, fixture_models, fixture_path

TOL = Tolerances()


# ----------------------------------------------------------------------------------- small pieces


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=10, max_size=10), st.integers(1, 3))
def test_reduced_side_stays_within_its_certified_bound(ys, q):
    """_reduce_side's per-axis bound holds at every sample (convex hull of the difference)."""
    k = 5
    u = np.linspace(0.0, 1.0, k + 1)
    v = np.array(ys[: k + 1]) * 0.2
    S = np.stack([u, v, np.ones(k + 1)], axis=1)
    R, (eu, ev), est = _reduce_side(S, q)
    assert not est
    t = np.linspace(0, 1, 101)
    from watertight_cli.core.bernstein import basis

    a = basis(k, t) @ S[:, :2]
    b = basis(R.shape[0] - 1, t) @ R[:, :2]
    assert np.all(np.abs(a[:, 0] - b[:, 0]) <= eu + 1e-14)
    assert np.all(np.abs(a[:, 1] - b[:, 1]) <= ev + 1e-14)
    assert np.allclose(R[[0, -1], :2], S[[0, -1], :2])  # ends kept


def test_own_parameter_detects_non_affine_edge_sides():
    line = np.array([[0.0, 1.0, 1.0], [0.5, 1.0, 1.0], [1.0, 1.0, 1.0]])
    bent = np.array([[0.0, 1.0, 1.0], [0.2, 1.0, 1.0], [1.0, 1.0, 1.0]])
    assert not _own_parameter(Side(line, True, edge=3))
    assert _own_parameter(Side(bent, True, edge=3))
    assert not _own_parameter(Side(bent, True))  # no edge: no parameter to keep


def test_close_loops_snaps_consecutive_ends_to_their_midpoint():
    from watertight_cli.untrim import _Coedge, _Piece

    def piece(a, b):
        return _Piece(np.array([[*a, 1.0], [*b, 1.0]]), 0, 0.0, 1.0, False)

    pa, pb = piece((0, 0), (1, 0)), piece((1, 1e-9), (0, 0))
    ce = _Coedge(0, False, None, 0.0, 1.0, np.array([0.0, 1.0]), np.zeros((1, 2, 3)))
    move = _close_loops([[(ce, [pa]), (ce, [pb])]])
    assert move == pytest.approx(0.5e-9)
    assert np.array_equal(pa.H[-1], pb.H[0])
    assert np.array_equal(pb.H[-1], pa.H[0])


# ------------------------------------------------------------------ a synthetic face, end to end


def _square_surface():
    """A bicubic patch over [0, 1]^2 as a one-span B-spline in the model's arrays."""
    from watertight_cli.model import BSplineSurface

    rng = np.random.default_rng(7)
    g = np.linspace(0, 1, 4)
    P = np.stack(np.meshgrid(g, g, indexing="ij"), -1)
    P = np.concatenate([P, 0.2 * rng.standard_normal((4, 4, 1))], axis=-1)
    kn = np.array([0, 0, 0, 0, 1, 1, 1, 1.0])
    return BSplineSurface(udegree=3, vdegree=3, uknots=kn, vknots=kn, poles=P, weights=None), P


def _square_context(P: np.ndarray, tol: float, max_degree: int) -> _FaceContext:
    """A face context over the one-span bicubic P on [0, 1]^2, without a face behind it."""
    ctx = _FaceContext.__new__(_FaceContext)
    ctx.face = type("F", (), {"index": 0})()
    ctx.rational, ctx.m, ctx.n = False, 3, 3
    ctx.ub = ctx.vb = np.array([0.0, 1.0])
    ctx.spans = P[None, None]
    ctx.tol, ctx.max_degree = tol, max_degree
    return ctx


def test_ruled_cell_under_a_cubic_trim_is_exact():
    """A cell between the v = 0 line and a cubic trim curve composes exactly (degree (6, 6*3))."""
    surf, P = _square_surface()
    ctx = _square_context(P, 1e-9, 25)
    bottom = Side(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]]), True)
    trim = np.array([[0.0, 0.6, 1.0], [0.3, 0.9, 1.0], [0.7, 0.5, 1.0], [1.0, 0.8, 1.0]])
    top = Side(trim, False, edge=1, w0=0.0, w1=1.0)
    from watertight_cli.untrim import FaceResult

    fr = FaceResult(0)
    patches = ctx.cell_patches(0.0, 1.0, bottom, top, fr)
    assert len(patches) == 1 and not fr.problems
    p = patches[0]
    assert p.degrees == (18, 6) and not p.approximated
    s = np.linspace(0, 1, 13)
    uv = cell_map(p, s, s).reshape(-1, 2)
    ref = surf.evaluate(uv).reshape(13, 13, 3)
    assert np.max(np.abs(patch_points(p, s, s) - ref)) < 1e-13


def test_an_inverted_approximated_cell_is_reported_once_not_halved():
    """A cell over the degree budget whose top runs below its bottom all along: both halves of it
    are inverted again, so it is reported at once. Halving it down to the deepest split made 2^14
    cells (ec_turbine's face 33 with plan rung cuts, 27 s of a 63 s conversion)."""
    _, P = _square_surface()
    ctx = _square_context(P, 1.0, 6)  # the cubic side composes to degree 18: approximated
    bottom = Side(np.array([[0.0, 0.6, 1.0], [1.0, 0.6, 1.0]]), True)
    low = np.array([[0.0, 0.1, 1.0], [0.3, 0.3, 1.0], [0.7, 0.1, 1.0], [1.0, 0.2, 1.0]])
    top = Side(low, False, edge=1, w0=0.0, w1=1.0)
    from watertight_cli.untrim import FaceResult

    fr = FaceResult(0)
    patches = ctx.cell_patches(0.0, 1.0, bottom, top, fr)
    assert len(patches) == 1
    assert fr.folds == 1 and len(fr.problems) == 1 and "inverted" in fr.problems[0]


# --------------------------------------------------------------------------- fixtures, pipeline


@pytest.fixture(scope="module")
def converted():
    """Every fixture through read -> untrim -> verify, once per test module."""
    from watertight_cli.inspect import inspect
    from watertight_cli.occ.build import input_face_areas
    from watertight_cli.untrim import untrim
    from watertight_cli.verify import verify_untrim

    out = {}
    for name in fixture_models():
        ins = inspect(str(fixture_path(name)), TOL)
        res = untrim(ins.model, TOL)
        out[name] = (ins, res, verify_untrim(ins.model, res, TOL, input_face_areas(ins.shape)))
    return out


@pytest.mark.parametrize("name", fixture_models())
def test_fixture_untrims_and_verifies(converted, name):
    ins, res, check = converted[name]
    assert check.ok, check.problems[:3]
    assert len(res.faces) == len(ins.model.faces)
    assert all(f.patches for f in res.faces)  # every face kept


@pytest.mark.parametrize("name", fixture_models())
def test_fixture_invariants(converted, name):
    ins, res, check = converted[name]
    diag = ins.model.diagonal
    for p in res.patches:  # I5: degrees within the budget
        assert max(p.degrees) <= TOL.max_degree
    for fr, fc in zip(res.faces, check.faces, strict=True):
        assert fc.folded == 0  # I5: no folds
        slack = TOL.exact_rel * diag
        if not fr.approximated and ins.model.faces[fr.face].approximation == 0 and fr.closure == 0:
            assert fc.deviation <= slack  # I4: exact where nothing was approximated
        assert fc.deviation <= fr.bound + slack  # I4: within the reported bound
        assert fr.bound <= TOL.approx_rel * diag + fr.closure + ins.model.faces[fr.face].approximation


def test_exact_fixture_patches_match_surface_tightly(converted):
    """The sphere converts without any approximation of our own: deviation at rounding level."""
    ins, res, check = converted["sphere.step"]
    assert not any(p.approximated for p in res.patches)
    assert max(c.deviation for c in check.faces) < 1e-12 * ins.model.diagonal


def test_patch_areas_add_up_to_the_face_areas(converted):
    ins, res, check = converted["plate_with_holes.step"]
    for fc in check.faces:
        assert fc.area_out == pytest.approx(fc.area_in, rel=1e-5)


def test_verify_catches_a_moved_patch(converted):
    """The verify step is not a rubber stamp: a patch shifted by 1e-6 of the diagonal fails."""
    from watertight_cli.verify import verify_untrim

    ins, res, _ = converted["torus.step"]
    p = res.faces[0].patches[0]
    moved = Patch(p.face, p.ctrl.copy(), p.rational, p.bottom, p.top, p.bound)
    shift = 1e-6 * ins.model.diagonal
    if moved.rational:
        moved.ctrl[..., 0] += shift * moved.ctrl[..., 3]
    else:
        moved.ctrl[..., 0] += shift
    res.faces[0].patches[0] = moved
    try:
        check = verify_untrim(ins.model, res, TOL)
        assert not check.ok
        assert any("deviation" in msg for msg in check.problems)
    finally:
        res.faces[0].patches[0] = p


def test_cells_cover_a_face_with_a_hole():
    """The plate's top face has holes: its cells' summed uv area equals the trimmed uv area."""
    from watertight_cli.inspect import inspect
    from watertight_cli.untrim import FaceResult, _face_pieces, _FaceGeometry, edge_plan

    ins = inspect(str(fixture_path("plate_with_holes.step")), TOL)
    m = ins.model
    geoms = [_FaceGeometry(f, m.diagonal, TOL) for f in m.faces]
    plan = edge_plan(m, geoms)
    holed = [f for f in m.faces if len(f.loops) > 1]
    assert holed
    face = holed[0]
    g = geoms[face.index]
    pieces, _, _ = _face_pieces(face, m, plan, g)
    fr = FaceResult(face.index)
    area = 0.0
    x, w = np.polynomial.legendre.leggauss(16)
    x, w = 0.5 * (x + 1), 0.5 * w
    for _ua, _ub, bot, top in _cells(face, pieces, g, fr):
        p = Patch(face.index, np.zeros((2, 2, 3)), False, bot, top)
        # uv area of the cell by quadrature of the ruled map's Jacobian
        h = 1e-7
        a = cell_map(p, x, x)
        du = (cell_map(p, np.clip(x + h, 0, 1), x) - cell_map(p, np.clip(x - h, 0, 1), x)) / (
            np.clip(x + h, 0, 1) - np.clip(x - h, 0, 1))[:, None, None]
        dt = (cell_map(p, x, np.clip(x + h, 0, 1)) - cell_map(p, x, np.clip(x - h, 0, 1))) / (
            np.clip(x + h, 0, 1) - np.clip(x - h, 0, 1))[None, :, None]
        jac = np.abs(du[..., 0] * dt[..., 1] - du[..., 1] * dt[..., 0])
        area += float(w @ jac @ w)
        assert a.shape == (16, 16, 2)
    # reference: the shoelace area of the loops' sampled uv polygons (outer minus holes)
    ref = 0.0
    for loop in face.loops:
        pts = []
        for ce in loop.coedges:
            ws = np.linspace(ce.first, ce.last, 200)
            uv = ce.pcurve.evaluate(ws)
            pts.append(uv[::-1] if ce.reversed else uv)
        poly = np.concatenate(pts)
        ref += 0.5 * (poly[:, 0] @ np.roll(poly[:, 1], -1) - poly[:, 1] @ np.roll(poly[:, 0], -1))
    assert area == pytest.approx(abs(ref), rel=1e-4)


def test_flatten_makes_a_wiggly_vertical_coedge_exact_and_pins_the_corners():
    """A near-vertical pcurve that wiggles by 1e-7 (as exporters write them) becomes the exact line
    u = const, and the loop closing keeps that u at both of its corners."""
    from watertight_cli.untrim import _close_loops, _Coedge, _flatten, _Piece

    class G:  # the two speed bounds and the thin width _flatten reads
        su, sv, thin = 1.0, 1.0, 0.0

    def chain_entry(points):
        H = np.concatenate([np.asarray(points, float), np.ones((len(points), 1))], axis=1)
        ce = _Coedge(0, False, None, 0.0, 1.0, np.array([0.0, 1.0]), np.zeros((1, 2, 3)))
        return ce, [_Piece(H, 0, 0.0, 1.0, False)]

    wiggly = chain_entry([(0.5, 0.0), (0.5 + 1e-7, 0.3), (0.5 - 1e-7, 0.7), (0.5 + 2e-8, 1.0)])
    top = chain_entry([(0.50000003, 1.0), (0.0, 1.0)])
    left = chain_entry([(0.0, 1.0), (0.0, 0.0)])
    bottom = chain_entry([(0.0, 0.0), (0.5, 0.0)])
    chains = [[bottom, wiggly, top, left]]
    fixed, flat = _flatten(chains, G, budget=1e-6)
    assert flat == pytest.approx(1e-7)
    u = wiggly[1][0].H[:, 0]
    assert np.all(u == u[0])  # exactly vertical
    _close_loops(chains, fixed)
    assert top[1][0].H[0, 0] == u[0] and bottom[1][0].H[-1, 0] == u[0]  # corners on the line
    assert np.array_equal(top[1][0].H[0, :2], wiggly[1][0].H[-1, :2])  # and the loop is closed


def test_flatten_leaves_curved_coedges_alone():
    from watertight_cli.untrim import _Coedge, _flatten, _Piece

    class G:
        su, sv, thin = 1.0, 1.0, 0.0

    H = np.array([[0.0, 0.0, 1.0], [0.3, 0.5, 1.0], [0.0, 1.0, 1.0]])
    ce = _Coedge(0, False, None, 0.0, 1.0, np.array([0.0, 1.0]), np.zeros((1, 2, 3)))
    fixed, flat = _flatten([[(ce, [_Piece(H.copy(), 0, 0.0, 1.0, False)])]], G, budget=1e-6)
    assert fixed == {} and flat == 0.0


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0, 1), min_size=2, max_size=30), st.floats(1e-9, 1e-2))
def test_slab_lines_and_nearest_agree(values, eps):
    """Every clustered value maps to a line within the cluster's reach, and lines are sorted."""
    from watertight_cli.untrim import _cluster, _nearest

    lines = _cluster(list(values), set(), eps)
    assert np.all(np.diff(lines) > eps)
    for x in values:
        k = _nearest(lines, x)
        assert abs(lines[k] - x) <= min(abs(lines - x)) + 1e-15


def test_pieces_are_recut_where_loop_closing_turns_them_back():
    """Closing a 5e-5 uv gap moved the end of a 1e-5-wide piece back past its start in u (seen in
    gmsh__wing_fuselage.step): the piece is cut again so that every piece stays u-monotone."""
    from watertight_cli.untrim import _monotone, _Piece

    H = np.array([[0.0, 0.0, 1.0], [1.0e-5, 0.1, 1.0], [1.2e-5, 0.2, 1.0], [-2.0e-5, 0.3, 1.0]])
    parts = _monotone(_Piece(H, 0, 0.0, 1.0, False), (1e-12, 1e-12))
    assert len(parts) == 2
    for p in parts:
        u = p.H[:, 0]
        assert np.all(np.diff(u) >= -1e-15) or np.all(np.diff(u) <= 1e-15)
    assert parts[0].w1 == parts[1].w0 and parts[0].w0 == 0.0 and parts[1].w1 == 1.0


def test_flatten_runs_straightens_a_near_vertical_stretch_of_a_long_pcurve():
    """A long pcurve that runs along u = 1 for a while with 1e-7 wiggles (gmsh__wing_fuselage.step):
    that stretch becomes exactly vertical, the rest stays, and the pieces still join."""
    from watertight_cli.untrim import _flatten_runs, _Piece

    def piece(pts):
        return _Piece(np.concatenate([np.asarray(pts, float), np.ones((len(pts), 1))], 1), 0, 0.0, 1.0, False)

    ps = [piece([(0.5, 0.0), (0.8, 0.1), (1.0, 0.2)]),
          piece([(1.0, 0.2), (1.0 + 1e-7, 0.3), (1.0 - 1e-7, 0.4)]),
          piece([(1.0 - 1e-7, 0.4), (1.0 + 5e-8, 0.5), (1.0, 0.6)]),
          piece([(1.0, 0.6), (0.8, 0.7), (0.5, 0.8)])]
    moved = _flatten_runs(ps, 0, 1e-6)
    assert 0 < moved <= 1e-6
    for p in ps[1:3]:
        assert np.ptp(p.H[:, 0]) == 0.0
    for a, b in zip(ps[:-1], ps[1:], strict=True):
        assert np.array_equal(a.H[-1], b.H[0])
    assert ps[0].H[0, 0] == 0.5 and ps[-1].H[-1, 0] == 0.5


def test_transposed_face_is_the_same_face():
    """Turning a face swaps u and v of its surface and pcurves: S(pc(w)) is unchanged at every
    edge parameter, the normal flips and ``reversed`` with it, and turning twice gives it back."""
    from watertight_cli.inspect import inspect
    from watertight_cli.untrim import transpose_face

    model = inspect(str(fixture_path("loft_minus_cylinder.step")), Tolerances(), array_gaps=False).model
    for face in model.faces:
        turned = transpose_face(face)
        assert turned.reversed is not face.reversed
        for a, b in zip((ce for lp in face.loops for ce in lp.coedges),
                        (ce for lp in turned.loops for ce in lp.coedges), strict=True):
            if a.pcurve is None:
                continue
            w = np.linspace(a.first, a.last, 7)
            pa = face.surface.evaluate(a.pcurve.evaluate(w))
            pb = turned.surface.evaluate(b.pcurve.evaluate(w))
            np.testing.assert_allclose(pa, pb, rtol=0, atol=1e-12 * model.diagonal)
        back = transpose_face(turned)
        np.testing.assert_array_equal(back.surface.poles, face.surface.poles)
        assert back.reversed is face.reversed and back.uv_bounds == face.uv_bounds


def test_plan_cuts_put_every_rung_along_an_edge_on_one_plan_piece():
    """A cell whose rung runs along a u-iso edge is cut at that edge's plan parameters, so each
    rung lies on one piece and can take the edge's curve in stage 2. filleted_freeform has rungs
    that span a plan cut when only vertices cut them."""
    from watertight_cli.inspect import inspect
    from watertight_cli.substitute import _rung_ref
    from watertight_cli.untrim import _FaceGeometry, _unshared_rungs, edge_plan, untrim, untrim_face

    model = inspect(str(fixture_path("plate_with_holes.step")), TOL, array_gaps=False).model
    res = untrim(model, TOL)
    along = shared = 0
    for fr in res.faces:
        eps = fr.eps
        for p in fr.patches:
            cm = cell_map(p, np.array([0.0, 1.0]), np.array([0.0, 1.0]))
            for a, b in (cm[0], cm[1]):
                lo, hi = min(a[1], b[1]) + eps[1], max(a[1], b[1]) - eps[1]
                ends = [(q, q.H[[0, -1], :2] / q.H[[0, -1], 2:3]) for q in fr.iso_pieces if not q.degenerate]
                on = [q for q, e in ends if abs(e[0, 0] - a[0]) <= 2 * eps[0]
                      and e[:, 1].min() < hi and e[:, 1].max() > lo]
                if on:
                    along += 1
                    shared += _rung_ref(fr.iso_pieces, a, b, eps) is not None
    assert along >= 18 and shared == along  # 18 since the plan's noise extrema went (``_extrema``)
    # the count that turning decides by agrees: none left here; with vertex cuts only,
    # filleted_freeform leaves rungs that span a plan cut (11 at d442458; plate_with_holes left two
    # until the plan stopped cutting at noise extrema, ``_extrema``), and none with plan cuts
    assert sum(_unshared_rungs(fr, 0.0) for fr in res.faces) == 0
    model = inspect(str(fixture_path("filleted_freeform.step")), TOL, array_gaps=False).model
    faces = [_FaceGeometry(f, model.diagonal, TOL) for f in model.faces]
    plan = edge_plan(model, faces, TOL.sliver_rel * model.diagonal)
    for cuts, unshared in (("vertices", lambda n: n > 0), ("plan", lambda n: n == 0)):
        left = sum(_unshared_rungs(untrim_face(f, model, plan, TOL, g, cuts), 0.0)
                   for f, g in zip(model.faces, faces, strict=True))
        assert unshared(left), (cuts, left)


def test_slab_lines_closer_than_a_sliver_in_3d_merge():
    """Two slab lines whose 3D distance stays below a sliver all along the face merge (a knot
    line wins); lines further apart somewhere along the face stay."""
    from watertight_cli.model import BSplineSurface, Face
    from watertight_cli.untrim import _FaceGeometry, _merge_thin

    # x = 1e-3 u v, y = v: a pole at v = 0; a u-gap du is 1e-3 du v wide in 3D
    uu, vv = np.meshgrid(np.linspace(0, 1, 2), np.linspace(0, 1, 2), indexing="ij")
    poles = np.stack([1e-3 * uu * vv, vv, 0.0 * uu], axis=-1)
    surf = BSplineSurface(1, 1, np.array([0.0, 0.0, 1.0, 1.0]), np.array([0.0, 0.0, 1.0, 1.0]), poles)
    face = Face(0, surf, "BSpline", False, (), (0.0, 1.0, 0.0, 1.0))
    g = _FaceGeometry(face, 1.0, TOL)  # sliver 1e-8
    lines = np.array([0.2, 0.5, 0.5 + 5e-6, 0.5 + 1e-4])
    # the knot line is pinned: beyond a sliver, nothing merges into its group
    out, index = _merge_thin(lines, {0.5 + 5e-6}, face, g, {}, {2})
    # 0.5 and 0.5 + 5e-6 are 5e-9 apart at most: merged, the knot line kept; 1e-4 -> 1e-7: kept
    np.testing.assert_array_equal(out, [0.2, 0.5 + 5e-6, 0.5 + 1e-4])
    np.testing.assert_array_equal(index, [0, 1, 1, 2])
    # unpinned, 1e-7 apart is within Tolerances.thin_rel (5e-7): the three lines become one
    out, index = _merge_thin(lines, {0.5 + 5e-6}, face, g, {}, set())
    np.testing.assert_array_equal(out, [0.2, 0.5 + 5e-6])
    np.testing.assert_array_equal(index, [0, 1, 1, 1])


def _square_with_cuts(top_cut: float, bottom_cut: float):
    """A unit square face (the plane z = 0) whose top side is cut at u = ``top_cut`` and its bottom
    side at ``bottom_cut``, as a neighbour's edge plan cuts them: pieces of a closed loop."""
    from watertight_cli.model import BSplineSurface, Face
    from watertight_cli.untrim import _Piece

    uu, vv = np.meshgrid(np.linspace(0, 1, 2), np.linspace(0, 1, 2), indexing="ij")
    surf = BSplineSurface(1, 1, np.array([0.0, 0.0, 1.0, 1.0]), np.array([0.0, 0.0, 1.0, 1.0]),
                          np.stack([uu, vv, 0.0 * uu], axis=-1))
    face = Face(0, surf, "BSpline", False, (), (0.0, 1.0, 0.0, 1.0))
    loop = [(0, 0), (bottom_cut, 0), (1, 0), (1, 1), (top_cut, 1), (0, 1)]
    pieces = [_Piece(np.array([[*a, 1.0], [*b, 1.0]]), k, 0.0, 1.0, False)
              for k, (a, b) in enumerate(zip(loop, loop[1:] + loop[:1], strict=True))]
    return face, pieces


def test_slab_lines_a_thin_strip_apart_merge_and_the_cells_still_tile_the_face():
    """trj8's planar faces 40 and 49: a neighbour's two cuts landed 4.1e-5 apart in u, far apart
    in v, and each made a slab line across the whole face, a strip 4.1e-5 x 42 that BRepMesh left
    partly untriangulated. Lines closer than Tolerances.thin_rel merge where every end on them is
    passed through: two cells, whose shared rung runs from one cut to the other, tile the face."""
    from watertight_cli.untrim import FaceResult, _cells, _FaceGeometry

    d = 2e-7  # in 3D too (the plane's speed is 1); the diagonal is 1: sliver 1e-8, thin 5e-7
    face, pieces = _square_with_cuts(0.5, 0.5 + d)
    g = _FaceGeometry(face, 1.0, TOL)
    cells = list(_cells(face, pieces, g, FaceResult(0)))
    assert len(cells) == 2
    (_, _, b0, t0), (_, _, b1, t1) = cells
    ends = [s.H[k, :2] / s.H[k, 2] for s in (b0, t0, b1, t1) for k in (0, -1)]
    # the left cell ends, and the right one starts, at both cuts: one shared (bent) rung
    np.testing.assert_array_equal(ends[1], ends[4])  # bottom: (0.5 + d, 0)
    np.testing.assert_array_equal(ends[3], ends[6])  # top: (0.5, 1)
    np.testing.assert_allclose(ends[1], [0.5 + d, 0.0])
    np.testing.assert_allclose(ends[3], [0.5, 1.0])
    # with thin merging off, the same face keeps the strip between the two lines
    g_off = _FaceGeometry(face, 1.0, TOL.with_(thin_rel=TOL.sliver_rel))
    assert len(list(_cells(face, pieces, g_off, FaceResult(0)))) == 3


def test_a_turning_end_pins_its_slab_line():
    """An end where both pieces leave to one side (a u-extremum of the loop) keeps its line: the
    cell beyond would run straight past it and leave a thin triangle uncovered. So does a piece
    that joins two lines of a group (it would become an iso piece), through ``links``."""
    from watertight_cli.untrim import _nearest, _Piece, _thin_merge_rules

    lines = np.array([0.0, 0.5, 0.5 + 1e-7, 1.0])

    def piece(a, b):
        return _Piece(np.array([[*a, 1.0], [*b, 1.0]]), 0, 0.0, 1.0, False)

    def rules(*pieces):
        at = [(_nearest(lines, float(p.H[0, 0])), _nearest(lines, float(p.H[-1, 0]))) for p in pieces]
        return _thin_merge_rules(lines, list(pieces), at, set())

    # (0.5 + 1e-7, 0.5) turns: both of its pieces run to the left
    links, pinned = rules(piece((0, 0.2), (0.5 + 1e-7, 0.5)), piece((0.5 + 1e-7, 0.5), (0, 0.8)))
    assert 2 in pinned
    # (0.5, 0.3) is passed through: line 1 stays free (the open ends pin lines 0 and 3)
    links, pinned = rules(piece((0, 0.3), (0.5, 0.3)), piece((0.5, 0.3), (1, 0.3)))
    assert pinned == {0, 3}
    # a piece from line 1 to line 2
    links, _ = rules(piece((0.5, 0.6), (0.5 + 1e-7, 0.6)))
    assert links == {2: 1}


def test_pcurve_end_near_a_rung_end_cuts_the_cells_only_there():
    """A pcurve end inside a neighbouring cell's rung a hair from its end cuts that cell along the
    v-iso line through it (gmsh__U_Joint_2.stp: a degenerate edge starts at 5.6e-5 of a rung's
    height from its top, and stage 2 moved that end by the input's 1.9e-5 gap; no polynomial of the
    degree budget bends the long rung so near its end, and 24 edges stayed free). The cut spreads
    to the next cell while it lands near a rung's end there; an end near the middle is left to
    stage 2's bend, a cut that would cross a cell's bottom or top is not made, and ends are
    matched to rungs by their slab line. Rung pieces that overlap out of step across a line are
    cut (fusee faces 93 and 165 had 6 free edges there)."""
    from watertight_cli.untrim import _align_rungs

    veps = 1e-9

    def cell(j, u0, u1, bottom, top, bmax=None, tmin=None):
        left = (np.array([u0, bottom[0]]), np.array([u0, top[0]]))
        right = (np.array([u1, bottom[1]]), np.array([u1, top[1]]))
        return [u0, u1, None, None, left, right, max(bottom) if bmax is None else bmax,
                min(top) if tmin is None else tmin, [], j, j + 1]

    # three slabs side by side, 0..1 in v; an end on line 1 (between slab 0 and slab 1) near v = 1
    cells = [cell(0, 0.0, 1.0, (0.0, 0.0), (1.0, 1.0)), cell(1, 1.0, 2.0, (0.0, 0.0), (1.0, 1.0)),
             cell(2, 2.0, 3.0, (0.0, 0.0), (1.0, 1.0))]
    _align_rungs(cells, [(1, 0.99994)], veps)
    assert [c[8] for c in cells] == [[0.99994]] * 3  # spread across the face
    # in the middle of the rung: nothing
    cells = [cell(0, 0.0, 1.0, (0.0, 0.0), (1.0, 1.0))]
    _align_rungs(cells, [(1, 0.5)], veps)
    assert cells[0][8] == []
    # the top runs down to 0.9 across the second cell: the line stops before it
    cells = [cell(0, 0.0, 1.0, (0.0, 0.0), (1.0, 1.0)), cell(1, 1.0, 2.0, (0.0, 0.0), (1.0, 0.9))]
    _align_rungs(cells, [(0, 0.99994)], veps)
    assert [c[8] for c in cells] == [[0.99994], []]
    # an end on another line than the rung's (a slab narrower than the clustering distance)
    cells = [cell(0, 0.0, 1.0, (0.0, 0.0), (1.0, 1.0))]
    _align_rungs(cells, [(2, 0.99994)], veps)
    assert cells[0][8] == []
    # rung pieces out of step across a line (cut at 0.6 on one side, 0.4 on the other): the
    # pieces [0, 0.6] and [0.4, 1] overlap and neither holds the other, so both are cut
    cells = [cell(0, 0.0, 1.0, (0.0, 0.0), (1.0, 1.0)), cell(1, 1.0, 2.0, (0.0, 0.0), (1.0, 1.0))]
    cells[0][8], cells[1][8] = [0.6], [0.4]
    _align_rungs(cells, [(0, 0.6), (1, 0.6), (1, 0.4), (2, 0.4)], veps)  # the cuts' ends, as _cells
    assert [c[8] for c in cells] == [[0.4, 0.6], [0.4, 0.6]]
    # a long piece that holds the other side's pieces is left to stage 2 (a T-vertex)
    cells = [cell(0, 0.0, 1.0, (0.0, 0.0), (1.0, 1.0)), cell(1, 1.0, 2.0, (0.0, 0.0), (1.0, 1.0))]
    cells[1][8] = [0.4]
    _align_rungs(cells, [(1, 0.4), (2, 0.4)], veps)
    assert [c[8] for c in cells] == [[], [0.4]]


def test_sides_crossing_just_before_a_tip_are_cut_at_the_crossing():
    """A cell's bottom and top that meet at one end of the slab (a tangential corner) but cross a
    hair before it (fusee face 110: 2.1e-5 in u, an inverted strip 3.4e-9 thick) are both cut where
    they cross, so the cell ends in a collapsed rung and is kept instead of dropped as thin. A
    crossing whose inverted strip is thicker than a sliver, sides that do not cross, and sides that
    meet at neither end are left alone."""
    from types import SimpleNamespace

    from watertight_cli.untrim import _eval, _Piece, _uncross

    def piece(vs):  # v as a Bezier in t = u on [0, 1]
        n = len(vs) - 1
        return _Piece(np.array([[k / n, v, 1.0] for k, v in enumerate(vs)]), 0, 0.0, 1.0, False)

    g = SimpleNamespace(sv=1.0, sliver=1e-6)
    bot = piece([0.0, 0.0])
    for c, ux in ((1e-4, 0.99), (1.0, 0.99999)):
        # top: v = c (u - 1)(u - ux): above bot before ux, below it (by <= c (1 - ux)^2 / 4) after
        top = piece([c * ux, c * (ux - (1 + ux) / 2), 0.0])
        out = _uncross(bot, top, g)
        assert out is not None
        for p in out:
            assert p.H[-1, 0] / p.H[-1, 2] == pytest.approx(ux, abs=1e-12)
        assert abs(_eval(out[1].H, 1.0)[0, 1] - _eval(out[0].H, 1.0)[0, 1]) < 1e-13
        # the same cell mirrored in u: the tip at the start
        mirror = [_Piece(np.array([[1 - h[0], h[1], 1.0] for h in p.H[::-1]]), 0, 0.0, 1.0, False)
                  for p in (bot, top)]
        out = _uncross(*mirror, g)
        assert out is not None
        assert out[0].H[0, 0] == pytest.approx(1 - ux, abs=1e-12)
    # the inverted strip 0.01^2 / 4 = 2.5e-5 thick: wider than a sliver
    assert _uncross(bot, piece([0.99, 0.99 - 1.99 / 2, 0.0]), g) is None
    # meeting at the tip without crossing, and not meeting at all
    assert _uncross(bot, piece([1.0, 0.0]), g) is None
    assert _uncross(bot, piece([1.0, 1.0]), g) is None


def _two_edge_model():
    """Stubs: edges 0 and 1 on [0, 1] meet at vertex 5 (edge 0 starts there, edge 1 ends there);
    face 0 has both, face 1 only edge 0, face 2 only edge 1, face 3 neither."""
    from types import SimpleNamespace

    def line(d):
        return SimpleNamespace(evaluate=lambda w: np.outer(np.asarray(w, dtype=float), d))

    edges = [SimpleNamespace(first=0.0, last=1.0, vertices=(5, 6), degenerate=False,
                             curve=line(np.array([1.0, 0.0, 0.0]))),
             SimpleNamespace(first=0.0, last=1.0, vertices=(7, 5), degenerate=False,
                             curve=line(np.array([0.0, 1.0, 0.0])))]

    def face(i, used):
        coedges = tuple(SimpleNamespace(edge=e) for e in used)
        return SimpleNamespace(index=i, loops=(SimpleNamespace(coedges=coedges),))

    faces = [face(0, (0, 1)), face(1, (0,)), face(2, (1,)), face(3, (9,))]
    return SimpleNamespace(edges=edges, faces=faces)


def test_a_crossing_cuts_the_neighbours_but_not_the_face_that_crossed():
    """Two pcurves of a face that cross a hair before their common vertex (fusee faces 60 and 110)
    leave the strip beyond the crossing to the face's neighbours, which meet each other there: the
    edge plan gets a cut at the crossing on both edges, and the neighbours are decomposed again
    with it. The face itself ends its cell at the crossing and is decomposed without its own cuts
    (with them, the inverted strip beyond became a cell of its own, with a free side). A crossing
    whose tails do not end at one vertex makes no cut."""
    from watertight_cli.untrim import FaceResult, UntrimResult, _crossing_cuts, crossing_tails

    model = _two_edge_model()
    fr = FaceResult(0)
    fr.crossings = [((1, 0.9, 1.0), (0, 0.2, 0.0))]  # bottom on edge 1, top on edge 0
    assert crossing_tails(model, fr) == [((0, 0.2, 0.0), (1, 0.9, 1.0))]
    plan = {0: np.array([0.5]), 1: np.zeros(0)}
    own = {}
    redo = _crossing_cuts(model, plan, [fr, FaceResult(1), FaceResult(2), FaceResult(3)], 1e-6, own)
    np.testing.assert_array_equal(plan[0], [0.2, 0.5])
    np.testing.assert_array_equal(plan[1], [0.9])
    assert own == {0: {0: {0.2}, 1: {0.9}}}
    assert redo == [1, 2]
    result = UntrimResult([fr], plan, 1e-6, 25, own_cuts=own)
    mine = result.plan_for(0)
    np.testing.assert_array_equal(mine[0], [0.5])
    assert len(mine[1]) == 0
    assert result.plan_for(1) is plan
    # tails that end short of the vertex, or at two different ones: no cut
    for crossing in (((1, 0.9, 0.95), (0, 0.2, 0.0)), ((1, 0.9, 0.0), (0, 0.2, 0.0))):
        fr.crossings = [crossing]
        assert crossing_tails(model, fr) == []
        plan = {0: np.array([0.5]), 1: np.zeros(0)}
        assert _crossing_cuts(model, plan, [fr], 1e-6, {}) == []
        np.testing.assert_array_equal(plan[0], [0.5])


@pytest.mark.slow
def test_a_face_with_a_pole_turns_when_its_rungs_cannot_take_their_edges():
    """A face with a pole (a degenerate edge) may be decomposed turned like any face without a
    seam: the pole is then a degenerate piece on a slab line, which its cell takes as a collapsed
    rung. gmsh__wing_fuselage.step face 13 has a pole and an edge (29) that wiggles around u = 0
    by 1e-4 over 180 spans: as is it made 11359 thin cells with 119 rungs along its edges that
    could not take their edge's curve (most of the wing's 717 free edges after stage 2), turned
    986 cells and none. Slow: the whole model is read and re-timed (about a minute)."""

    from watertight_cli.inspect import inspect
    from watertight_cli.sameparam import retime
    from watertight_cli.untrim import RUNG_SLIDE, _unshared_rungs, untrim

    tol = Tolerances()
    model = inspect(str(corpus_path("gmsh__wing_fuselage.step")), tol, array_gaps=False).model
    retime(model, tol)
    face = model.faces[13]
    assert any(model.edges[ce.edge].degenerate for lp in face.loops for ce in lp.coedges)
    assert not any(model.edges[ce.edge].seam for lp in face.loops for ce in lp.coedges)
    half = tol.with_(approx_rel=0.5 * tol.approx_rel)
    fr = untrim(model, half).faces[13]  # the whole model: the tails look up faces by their index
    assert model.faces[13] is not face and model.faces[13].reversed != face.reversed  # turned
    assert not fr.problems
    assert _unshared_rungs(fr, RUNG_SLIDE * half.approx_rel * model.diagonal) == 0
    assert len(fr.patches) < 2000


def test_a_face_whose_repairs_cost_much_as_is_is_decomposed_turned():
    """gmsh__917_fusee.stp's face 6: both u-sides wiggle around u = 0 and u = 1 by 3e-5. As is, its
    repairs cost 1.7e-4 (of a 2.4e-4 tolerance; 1.2e-4 of it flattening) and made 163 cells along
    the wiggles, whose rungs stage 2 could not all share (7 free edges once thin slab lines merged
    there); turned, the face needs no flattening. A face whose flattening exceeds the rung slide is
    tried turned, and kept so when that flattens less than half as much with no more patches."""
    from watertight_cli.inspect import inspect

    ins = inspect(str(corpus_path("gmsh__917_fusee.stp")), TOL, array_gaps=False)
    face = replace(ins.model.faces[6], index=0)
    model = replace(ins.model, faces=[face])
    tol = TOL.with_(approx_rel=0.5 * TOL.approx_rel)
    res = untrim(model, tol)
    assert model.faces[0] is not face  # turned
    assert res.faces[0].flattened < 1e-6 * tol.approx_rel * model.diagonal


def test_thin_patch_counts_slivers_below_the_tolerance_and_not_pole_triangles():
    """I5, "no slivers below the tolerance": a patch whose opposite sides stand closer than the
    tolerance all along while it is long is thin; a square is not, nor a triangle whose collapsed
    side sits at a pole (its sides meet there, but the patch is as wide as it is long)."""
    from watertight_cli.verify import thin_patch

    s = np.linspace(0.0, 1.0, 9)
    S, T = np.meshgrid(s, s, indexing="ij")

    def grid(x, y):
        return np.stack([x, y, 0.0 * x], axis=-1)

    width = 1e-3
    assert thin_patch(grid(42.0 * S, 4e-4 * T), width)  # trj8's strip: 4e-4 x 42
    assert thin_patch(grid(4e-4 * S, 42.0 * T), width)  # the same, turned
    assert not thin_patch(grid(S, T), width)
    assert not thin_patch(grid(S * T, T), width)  # a triangle: its side s = 0 collapsed at the pole
    assert not thin_patch(grid(5e-3 * S, 4e-4 * T), width)  # small, but not long: not a sliver
    # 4e-4 wide and 42 long with its top end slanted 2 along it: the corners of that end stand 2
    # apart, the sides 4e-4 all along
    assert thin_patch(grid(4e-4 * S, 42.0 * T + 2.0 * S * T), width)
    assert not thin_patch(grid(0.5 * S, 42.0 * T + 2.0 * S * T), width)


def _thin_reference(along_s: np.ndarray, along_t: np.ndarray, width: float) -> bool:
    """``verify.thin_sides`` written out for one patch: every sample of a side against every
    segment of the opposite side's polyline, the 0.75 quantile of the nearest distances."""
    def gap(a, b):
        near = []
        for x in a:
            best = np.inf
            for p, q in zip(b[:-1], b[1:], strict=True):
                d = q - p
                t = min(max(float(np.dot(x - p, d) / max(np.dot(d, d), 1e-300)), 0.0), 1.0)
                best = min(best, float(np.linalg.norm(x - (p + t * d))))
            near.append(best)
        return float(np.quantile(near, 0.75))

    across_t = max(gap(along_s[:, 0], along_s[:, 1]), gap(along_s[:, 1], along_s[:, 0]))
    across_s = max(gap(along_t[0], along_t[1]), gap(along_t[1], along_t[0]))
    length = max(np.linalg.norm(np.diff(along_s, axis=0), axis=-1).sum(axis=0).max(),
                 np.linalg.norm(np.diff(along_t, axis=1), axis=-1).sum(axis=1).max())
    return min(across_t, across_s) < width and length > 10.0 * width


@settings(max_examples=25, deadline=None)
@given(st.integers(1, 40), st.integers(0, 2**32 - 1), st.floats(1e-3, 0.5))
def test_thin_check_of_many_patches_matches_the_one_patch_definition(count, seed, width):
    """The verify step measures all patches of a face at once and skips those whose opposite
    sides' boxes stand ``width`` apart; the flags are those of the plain definition per patch."""
    from watertight_cli.verify import thin_sides_many

    rng = np.random.default_rng(seed)
    size = rng.uniform(1e-4, 1.0, (count, 1, 1, 1))
    along_s, along_t = rng.normal(size=(count, 9, 2, 3)) * size, rng.normal(size=(count, 2, 9, 3)) * size
    squash = rng.random(count) < 0.5  # sides close to each other, some within ``width``
    along_s[squash, :, 1] = along_s[squash, :, 0] + 1e-3 * rng.normal(size=(int(squash.sum()), 9, 3))
    along_t[squash, 1] = along_t[squash, 0] + 1e-3 * rng.normal(size=(int(squash.sum()), 9, 3))
    got = thin_sides_many(along_s, along_t, width)
    assert got.tolist() == [_thin_reference(a, b, width) for a, b in zip(along_s, along_t, strict=True)]


def _cusp_model(c: float):
    """Two quadratic edges leaving vertex 0 at the origin along x: a = (w, c w^2, 0) and
    b = (w, -c w^2, 0), w in [0, 1], 2 c w^2 apart (a cusp for c small)."""
    from types import SimpleNamespace

    from watertight_cli.model import BSplineCurve

    knots = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
    edges = [SimpleNamespace(curve=BSplineCurve(2, knots, np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0],
                                                                    [1.0, s * c, 0.0]])),
                             first=0.0, last=1.0, vertices=(0, k + 1))
             for k, s in enumerate((1.0, -1.0))]
    return SimpleNamespace(edges=edges, vertices=np.array([[0.0, 0.0, 0.0], [1.0, c, 0.0], [1.0, -c, 0.0]]))


def test_a_cusp_tail_ends_at_the_farthest_corner_pair_within_the_joining_distance():
    """Two edges of a face that leave a vertex tangentially, 2 c w^2 apart: the tail runs to the
    farthest pair of the face's corners (one on each edge) within eps of each other over the whole
    stretch; a corner without a partner on the other edge is passed over; edges at an angle, or a
    tail shorter than 10 eps, give none (``untrim.cusp_tails``)."""
    from watertight_cli.untrim import _cusp, _tangent

    eps = 1e-7
    model = _cusp_model(1e-3)  # 2e-9 apart at w = 1e-3, 2e-7 at 1e-2
    assert _tangent(model, 0, 0.0, 1, 0.0)
    corners = {1e-4, 5e-4, 1e-3, 1e-2, 0.1, 1.0}
    tail = _cusp(model, 0, (0, 0.0, corners | {7e-4}), (1, 0.0, corners), eps)
    assert tail == ((0, 1e-3, 0.0), (1, 1e-3, 0.0))
    assert _cusp(model, 0, (0, 0.0, {5e-7}), (1, 0.0, {5e-7}), eps) is None  # shorter than 10 eps
    assert _cusp(model, 0, (0, 0.0, {1e-2}), (1, 0.0, {1e-2}), eps) is None  # 2e-7 apart
    wide = _cusp_model(1.0)
    wide.edges[1].curve.poles[1] = [0.5, -0.5, 0.0]  # leaves the vertex at 45 degrees
    assert not _tangent(wide, 0, 0.0, 1, 0.0)


def test_cusps_of_a_real_file_are_cut_into_every_face_of_their_edges():
    """Where a wedge face narrows to nothing between two tangent edges, its cells near the tip were
    dropped as flat and the faces beyond met each other 2.6e-9 apart (gmsh__U_Joint_2.stp, 12 such
    cusps; I2's goal missed). Stage 1 finds each cusp's (or crossing's) tail and puts its far end
    into the edge plan, so every face on both edges has a corner there, and stage 2 gives both
    tails one curve. Since the plan no longer cuts at extrema that turn back by noise before an
    edge's end (``_extrema``), U_Joint's tips hold no cell to drop and it has no tail; fusee still
    has three. About a minute and a half."""
    from watertight_cli.inspect import inspect
    from watertight_cli.sameparam import retime
    from watertight_cli.substitute import IsoPieces, _refs
    from watertight_cli.untrim import RUNG_SLIDE, crossing_tails, untrim

    model = inspect(str(corpus_path("gmsh__917_fusee.stp")), TOL, array_gaps=False).model
    retime(model, TOL)
    res = untrim(model, TOL)
    tails = {t for fr in res.faces for t in crossing_tails(model, fr)}
    assert len(tails) >= 3
    slide = RUNG_SLIDE * TOL.approx_rel * model.diagonal
    corners: dict[int, dict[int, set[float]]] = {}
    for fr in res.faces:
        iso = IsoPieces(fr.iso_pieces)
        for p in fr.patches:
            for ref in _refs(p, iso, fr.eps, slide)[0].values():
                if ref is not None and not ref.pole and ref.along is None:
                    corners.setdefault(ref.edge, {}).setdefault(fr.face, set()).update((ref.wa, ref.wb))
    for tail in tails:
        for e, x, _ in tail:
            for face, ws in corners[e].items():
                assert min(abs(w - x) for w in ws) <= 1e-9 * abs(x), (e, x, face)


def _degenerate_sides(res) -> list[tuple[int, int, str]]:
    """(face, patch, side) of every patch side along which S_s x S_t vanishes at 1/4, 1/2 and 3/4."""
    from watertight_cli.core.triangle import _homogeneous, _point_derivatives

    g = np.array([0.25, 0.5, 0.75])
    z, o = np.zeros(3), np.ones(3)
    found = []
    for fr in res.faces:
        for k, p in enumerate(fr.patches):
            H = _homogeneous(p.ctrl, p.rational)
            size = float(np.ptp((H[..., :3] / H[..., 3:4]).reshape(-1, 3), axis=0).max())
            for name, (s, t) in {"left": (z, g), "right": (o, g), "bottom": (g, z), "top": (g, o)}.items():
                _, xs, xt = _point_derivatives(H, s, t)
                if np.linalg.norm(np.cross(xs, xt), axis=1).max() <= 1e-9 * size**2:
                    found.append((fr.face, k, name))
    return found


def test_no_patch_side_where_the_jacobian_vanishes_all_along(tmp_path):
    """A plate with two round holes one above the other: the holes' extremes in u lie on the same
    two slab lines, and the cell between the holes has a bottom and a top that leave both its
    rungs tangent to them, so the cell map's S_s runs along each rung all the way up it. Such a
    cell is cut along a v-iso line (``untrim._tangent_rung_cuts``); without the cut, four sides
    (two per plane) are degenerate. On gmsh__Block.stp six such strips, 0.0098 wide, got no
    triangulation from OCCT's mesher."""
    import cadquery as cq

    from watertight_cli.inspect import inspect

    plate = cq.Workplane("XY").box(20, 40, 2).faces(">Z").workplane().pushPoints([(0, -8), (0, 8)]).hole(6)
    path = tmp_path / "plate.step"
    cq.exporters.export(plate, str(path))
    res = untrim(inspect(str(path), TOL).model, TOL)
    assert not _degenerate_sides(res)
    assert not any(fr.problems for fr in res.faces)


def test_a_plan_cut_a_sliver_from_a_knot_line_is_dropped():
    """A plan cut (an edge plan's parameter, not a vertex of the face) whose line stands within a
    sliver of a knot line on both rungs of its cell, but farther than the distance at which stage 2
    makes corners one, would leave a cell too thin for anything: U_Joint_2 face 103 had one 7.1e-7
    wide beside its knot line (the neighbour's knot, which this face's pcurve put 2.8e-8 off in v),
    kept as a triangle. The knot line stays; vertices, thinner cells and farther cuts are kept."""
    from types import SimpleNamespace

    from watertight_cli.untrim import _sliver_cuts_dropped

    diagonal = 100.0  # sliver 1e-6, merge distance 4e-7
    face = SimpleNamespace(surface=SimpleNamespace(
        evaluate=lambda uv: np.column_stack([uv[:, 0], uv[:, 1], np.zeros(len(uv))])))
    g = SimpleNamespace(sliver=TOL.sliver_rel * diagonal, diagonal=diagonal)
    left, right = (np.array([0.0, 0.0]), np.array([0.0, 1.0])), (np.array([1.0, 0.0]), np.array([1.0, 1.0]))
    thin, hair, wide = 0.5 + 7e-7, 0.5 - 2e-7, 0.5 + 5e-6
    cuts = [0.5, thin, hair, wide]
    assert _sliver_cuts_dropped(cuts, {0.5}, {thin, hair, wide}, face, left, right, g) == [0.5, hair, wide]
    assert _sliver_cuts_dropped(cuts, {0.5}, {hair, wide}, face, left, right, g) == cuts  # thin: a vertex



def test_the_plan_keeps_one_of_two_pcurve_knots_closer_than_thin():
    """Two faces' pcurve knots a few 1e-6 apart on one edge (trj8 edge 116, one pcurve re-timed):
    the plan keeps one, and the face whose knot is left out still cuts its own pcurve there. Plan
    values that are no pcurve knot go only within a sliver; a knot farther than ``thin`` stays."""
    from types import SimpleNamespace

    from watertight_cli.untrim import _thin_plan

    edge = SimpleNamespace(first=0.0, last=1.0, curve=SimpleNamespace(
        evaluate=lambda w: np.column_stack([np.asarray(w, float), np.zeros(len(w)), np.zeros(len(w))])))
    sliver, thin = 1e-6, 5e-5
    params = np.array([0.25, 0.25 + 8e-6, 0.5, 0.5 + 8e-6, 0.75, 0.75 + 1e-4, 0.9, 0.9 + 5e-7])
    knots = {0.25 + 8e-6, 0.75 + 1e-4, 0.9 + 5e-7}
    np.testing.assert_array_equal(_thin_plan(params, edge, sliver, thin, knots),
                                  [0.25, 0.5, 0.5 + 8e-6, 0.75, 0.75 + 1e-4, 0.9])
    # without ``thin`` only the sliver rule applies
    np.testing.assert_array_equal(_thin_plan(params, edge, sliver), params[:-1])

def test_a_rung_cut_at_a_pcurve_knot_the_plan_left_out_is_dropped_beside_a_near_cut():
    """The edge plan keeps one of two parameters a hair apart (the 3D curve's knot and the
    pcurve's), but the pcurve is still cut at its own knot; a cut across the cell at that end
    stood within a sliver of the plan's cut on both rungs, and stage 2 made a needle of the band
    between them (trj8 faces 44, 54 and 55: up to 1.3e-6 wide, 0.19 long). Such a cut is dropped;
    plan cuts, cuts farther than a sliver on either rung and cuts thinner than the merge distance
    everywhere (dropped as flat later) are kept."""
    from types import SimpleNamespace

    from watertight_cli.untrim import _knot_cuts_dropped

    diagonal = 100.0  # sliver 1e-6, merge distance 4e-7
    face = SimpleNamespace(surface=SimpleNamespace(
        evaluate=lambda uv: np.column_stack([uv[:, 0], uv[:, 1], np.zeros(len(uv))])))
    g = SimpleNamespace(sliver=TOL.sliver_rel * diagonal, diagonal=diagonal)
    left, right = (np.array([0.0, 0.0]), np.array([0.0, 1.0])), (np.array([1.0, 0.0]), np.array([1.0, 1.0]))
    knot, far, flat = 0.3 + 8e-7, 0.6 + 3e-6, 0.8 + 1e-7
    cuts = [0.3, knot, 0.6, far, 0.8, flat]
    assert _knot_cuts_dropped(cuts, {knot, far, flat}, face, left, right, g) == [0.3, 0.6, far, 0.8, flat]
    assert _knot_cuts_dropped(cuts, set(), face, left, right, g) == cuts  # every end at a plan cut
    # the band narrows to a hair at the left rung and widens past a sliver at the right one: kept
    slanted = SimpleNamespace(surface=SimpleNamespace(
        evaluate=lambda uv: np.column_stack([uv[:, 0], uv[:, 1] * (1 + 2 * uv[:, 0]), np.zeros(len(uv))])))
    assert _knot_cuts_dropped([0.3, knot], {knot}, slanted, left, right, g) == [0.3, knot]
    # a knot cut beside another knot cut: one of the two goes, the band is gone
    assert len(_knot_cuts_dropped([0.3, knot], {0.3, knot}, face, left, right, g)) == 1

def _square_with_hole(bottom_cut: float, top_cut: float):
    """The unit square face of ``_square_with_cuts`` with a rectangular hole [0.3, 0.7] x [0.4, 0.6]
    whose lower side is cut at u = ``bottom_cut`` and its upper side at ``top_cut``."""
    from watertight_cli.untrim import _Piece

    face, pieces = _square_with_cuts(0.5, 0.5)
    pieces = [p for p in pieces if not np.array_equal(p.H[0, :2], [0.5, 0]) and not np.array_equal(
        p.H[0, :2], [0.5, 1])]  # the outer sides uncut again: (0, 0) -> (1, 0), (1, 1) -> (0, 1)
    pieces = [replace(p, H=np.array([p.H[0], [1.0 - p.H[0, 0], p.H[0, 1], 1.0]])) if p.H[0, 1] == p.H[1, 1]
              else p for p in pieces]
    hole = [(0.3, 0.4), (0.3, 0.6), (top_cut, 0.6), (0.7, 0.6), (0.7, 0.4), (bottom_cut, 0.4)]  # clockwise
    pieces += [_Piece(np.array([[*a, 1.0], [*b, 1.0]]), 10 + k, 0.0, 1.0, False)
               for k, (a, b) in enumerate(zip(hole, hole[1:] + hole[:1], strict=True))]
    return face, pieces


def test_a_cell_runs_through_a_slab_line_that_only_other_pieces_end_on():
    """bspline_boolean's face with a hole: the edge plan cut the hole's upper and lower halves at
    different u, and every cut made a slab line across the whole face, so the cells above and below
    the hole were cut where nothing on their own bottom or top ends (156 of its 546 patches more
    than 1000 times longer than wide). A cell now runs through such a line: the region between
    the same two pieces on both sides of it, with no piece end on it between them, is one cell."""
    from watertight_cli.untrim import FaceResult, _cells, _FaceGeometry

    face, pieces = _square_with_hole(0.45, 0.55)
    g = _FaceGeometry(face, 1.0, TOL)
    cells = list(_cells(face, pieces, g, FaceResult(0)))
    spans = sorted((round(ua, 9), round(ub, 9), round(float(bot.H[0, 1] / bot.H[0, 2]), 9))
                   for ua, ub, bot, _ in cells)
    # beside the hole its vertical sides cut the cells (rungs along the edges); below it the cells
    # are cut only at the lower side's cut (0.45), above it only at the upper side's (0.55)
    assert spans == [(0.0, 0.3, 0.0), (0.0, 0.3, 0.4), (0.0, 0.3, 0.6), (0.3, 0.45, 0.0), (0.3, 0.55, 0.6),
                     (0.45, 0.7, 0.0), (0.55, 0.7, 0.6), (0.7, 1.0, 0.0), (0.7, 1.0, 0.4), (0.7, 1.0, 0.6)]
    # the cells tile the face: their uv areas (straight sides) add up to the square less the hole
    area = sum((ub - ua) * 0.5 * ((top.H[0, 1] - bot.H[0, 1]) + (top.H[-1, 1] - bot.H[-1, 1]))
               for ua, ub, bot, top in cells)
    assert area == pytest.approx(1.0 - 0.4 * 0.2, abs=1e-12)
    # cuts at the same u on both halves make no cell that spans lines
    cells = list(_cells(face, _square_with_hole(0.5, 0.5)[1], g, FaceResult(0)))
    assert sorted(round(ub - ua, 9) for ua, ub, _, _ in cells) == [0.2] * 4 + [0.3] * 6


def test_plan_cuts_that_end_strips_are_left_out(converted):
    """bspline_boolean's faces: plan cuts that only a neighbour needs stood close in u to a knot
    line or a vertex, and each made a strip across its slab (face 0: 19 of 176 patches more than 500
    times longer than wide, one 0.04 x 75 beside its knot line u = 0.25). Those cuts are left out
    of the face where that leaves fewer strips: its side runs through them (the neighbour's corner
    is a T-vertex on it). The faces keep every cut they need themselves, and stage 2 fits no curve
    with a break at a cut some face left out."""
    from watertight_cli.untrim import _defects, _droppable_cuts, _face_or_problem, _FaceGeometry

    ins, res, check = converted["bspline_boolean.step"]
    assert check.ok
    m = ins.model
    left_out = [fr for fr in res.faces if fr.strip_cuts]
    assert left_out
    for fr in left_out:
        face = m.faces[fr.face]
        g = _FaceGeometry(face, m.diagonal, TOL)
        full = _face_or_problem(face, m, res.plan, TOL, g)
        assert _defects(fr, g) < _defects(full, g)
        free = _droppable_cuts(face, m, res.plan, g)
        for e, ws in res.own_cuts[fr.face].items():
            assert ws <= free.get(e, set())  # only cuts the face itself does not need
            assert not set(map(float, res.shared_cuts(e))) & ws
            # the face's sides on e run through the cuts: no side ends at one
            ends = {w for p in fr.patches for s in (p.bottom, p.top) if s.edge == e for w in (s.w0, s.w1)}
            assert not any(min(abs(w - x) for x in ends) < 1e-12 for w in ws)


def test_a_piece_alone_nearly_on_a_slab_line_goes_onto_the_line_through_its_turning_end():
    """bspline_boolean face 0: a pcurve turns back at u = A (its extremum) and has a knot 6e-5
    further in v, where u = A + 3e-8. The piece between stood on two slab lines 3e-6 apart in 3D,
    a strip 33 long. Flattened, it lies on u = A; the next piece starts there; the piece that
    turns at A keeps its end."""
    from watertight_cli.untrim import _flatten_runs, _Piece

    def piece(*pts):
        return _Piece(np.array([[u, v, 1.0] for u, v in pts]), 3, 0.0, 1.0, False)

    A = 0.288
    up = piece((A + 0.01, 0.7), (A, 0.6))  # comes down to the extremum
    tiny = piece((A, 0.6), (A + 1e-8, 0.59997), (A + 3e-8, 0.59994))
    down = piece((A + 3e-8, 0.59994), (A + 0.02, 0.3))
    ps = [up, tiny, down]
    moved = _flatten_runs(ps, 0, half=0.0, single=1e-7)
    assert moved == pytest.approx(3e-8)
    assert np.all(tiny.H[:, 0] == A) and down.H[0, 0] == A and up.H[-1, 0] == A
    assert down.H[-1, 0] == A + 0.02 and up.H[0, 0] == A + 0.01
    # wider than ``single``: left as it is
    ps = [piece((A + 0.01, 0.7), (A, 0.6)), piece((A, 0.6), (A + 3e-6, 0.59994)),
          piece((A + 3e-6, 0.59994), (A + 0.02, 0.3))]
    assert _flatten_runs(ps, 0, half=0.0, single=1e-7) == 0.0 and ps[1].H[-1, 0] == A + 3e-6


def _square_cut_on_its_sides(left: float, right: float):
    """The unit square face of ``_square_with_cuts`` whose left side is cut at v = ``left`` and its
    right side at ``right``, as the neighbours' edge plans cut them."""
    from watertight_cli.untrim import _Piece

    face, _ = _square_with_cuts(0.5, 0.5)
    loop = [(0, 0), (1, 0), (1, right), (1, 1), (0, 1), (0, left)]
    pieces = [_Piece(np.array([[*a, 1.0], [*b, 1.0]]), k, 0.0, 1.0, False)
              for k, (a, b) in enumerate(zip(loop, loop[1:] + loop[:1], strict=True))]
    return face, pieces


def test_cuts_on_opposite_rungs_closer_than_thin_make_one_slanted_cut():
    """ec_turbine face 13: the edges on its two sides were cut by their neighbours' plans 2e-6
    apart in v, and the two v-iso cuts across the face bounded a band below the tolerance. Such a
    pair is one straight cut from the one point to the other; farther apart they stay two."""
    from watertight_cli.untrim import FaceResult, _cells, _FaceGeometry

    face, pieces = _square_cut_on_its_sides(0.5, 0.5 + 2e-7)  # diagonal 1: sliver 1e-8, thin 5e-7
    g = _FaceGeometry(face, 1.0, TOL)
    cells = list(_cells(face, pieces, g, FaceResult(0)))
    assert len(cells) == 2
    (_, _, b0, t0), (_, _, b1, t1) = cells
    assert t0 is b1 and not t0.iso
    assert np.allclose(t0.H[:, :2], [[0.0, 0.5], [1.0, 0.5 + 2e-7]], rtol=0, atol=1e-15)
    face, pieces = _square_cut_on_its_sides(0.5, 0.5 + 2e-6)
    cells = list(_cells(face, pieces, g, FaceResult(0)))
    assert len(cells) == 3 and all(t.iso for _, _, _, t in cells[:-1])


def test_plan_cuts_that_end_bands_are_left_out():
    """occt__ec_turbine-A.stp: the edges along a face's sides carry cuts that the neighbours' plans
    put a hair from the face's own (2e-6 apart in v on face 13), and the v-iso cuts through both
    bounded bands across the face, their rungs under 1/200 of their bottom and top (face 6: nine).
    Such a neighbour's cut is left out of the face where that leaves fewer strips and bands; the
    face keeps every cut it needs itself. About ten seconds."""
    from watertight_cli.inspect import inspect
    from watertight_cli.untrim import (
        _bands,
        _defects,
        _droppable_cuts,
        _face_or_problem,
        _FaceGeometry,
        untrim,
    )

    m = inspect(str(corpus_path("occt__ec_turbine-A.stp")), TOL, array_gaps=False).model
    res = untrim(m, TOL)
    before = after = 0
    for fr in res.faces:
        if not fr.strip_cuts:
            continue
        face = m.faces[fr.face]
        g = _FaceGeometry(face, m.diagonal, TOL)
        full = _face_or_problem(face, m, res.plan, TOL, g)
        assert _defects(fr, g) < _defects(full, g)
        before += len(_bands(full, g.sliver))
        after += len(_bands(fr, g.sliver))
        free = _droppable_cuts(face, m, res.plan, g)
        for e, ws in res.own_cuts[fr.face].items():
            assert ws <= free.get(e, set())
        if fr.face == 6:
            assert len(_bands(full, g.sliver)) >= 4 and not _bands(fr, g.sliver)
    # 34 -> 19 at d442458, face 6 4 -> 0 (it had nine before the plan stopped cutting at extrema
    # that turn back by noise before a piece's end, ``_extrema``)
    assert after < 0.6 * before


def _needle(width: float, meet: bool = True, iso: bool = False):
    """A cell of edge 1 whose bottom and top meet at s = 1 (a loop's tip, when ``meet``), as a
    bilinear triangle in 3D: its left rung runs from (0, 0, 0) to (0, 1, 0), its tip stands
    ``width`` off the rung's middle."""
    from watertight_cli.untrim import Patch, Side

    tip = np.array([width, 0.5, 0.0])
    ctrl = np.array([[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [tip, tip if meet else tip + [0.0, 0.1, 0.0]]])
    bottom = Side(np.array([[0.2, 0.1, 1.0], [0.3, 0.5, 1.0]]), iso, None if iso else 1, 0.4, 0.5)
    top = Side(np.array([[0.2, 0.9, 1.0], [0.3, 0.5 if meet else 0.6, 1.0]]), False, 1, 0.6, 0.5)
    return Patch(0, ctrl, False, bottom, top)


def test_a_cap_is_a_needle_when_thin_or_slender():
    """``_caps``: a cell whose bottom and top are edge pieces meeting at one end is a needle cap
    when it lies within ``thin`` of its other rung, or when that rung is more than ``_NEEDLE`` times
    longer than the cell is wide; a fat cap, a cell whose sides do not meet, and one with an iso
    side are not."""
    from watertight_cli.untrim import _NEEDLE, FaceResult, _caps

    def caps(*patches, thin=1e-9):
        return _caps(FaceResult(0, patches=list(patches)), thin, 1e-12, 1e-12)

    slender = _needle(0.5 / _NEEDLE)
    assert [(p, end) for p, end in caps(slender)] == [(slender, -1)]
    assert not caps(_needle(2.0 / _NEEDLE))  # fat: the build's quad has its flat corners apart
    assert len(caps(_needle(2.0 / _NEEDLE), thin=0.1)) == 1  # within thin
    assert not caps(_needle(1e-4, meet=False))
    assert not caps(_needle(1e-4, iso=True))


def test_plan_cuts_that_end_needle_caps_are_left_out():
    """occt__bug24595_281390.stp face 3: a slab line 1e-5 in u short of the tip of edge 6 (its
    u-extremum), through a plan cut of the cylinder beside it, left a cap 0.051 long and 3.9e-4
    wide; its quads had corners on one line and the read-back mesh two-corner triangles. Without
    that cut (only the cylinder needs it) the cap reaches the next slab line; the face keeps every
    cut it needs itself."""
    from watertight_cli.inspect import inspect
    from watertight_cli.untrim import (
        RUNG_SLIDE,
        _caps,
        _droppable_cuts,
        _face_or_problem,
        _FaceGeometry,
        _without_strip_cuts,
        edge_plan,
    )

    m = inspect(str(corpus_path("occt__bug24595_281390.stp")), TOL, array_gaps=False).model
    geoms = [_FaceGeometry(face, m.diagonal, TOL) for face in m.faces]
    plan = edge_plan(m, geoms, TOL.sliver_rel * m.diagonal, max(TOL.thin_rel, TOL.sliver_rel) * m.diagonal)
    face, g = m.faces[3], geoms[3]
    full = _face_or_problem(face, m, plan, TOL, g)
    before = _caps(full, g.thin, g.ueps_lines, g.veps)
    assert any(p.bottom.edge == 6 for p, _ in before)
    fr, drops = _without_strip_cuts(face, m, plan, full, TOL, g, RUNG_SLIDE * TOL.approx_rel * m.diagonal)
    assert 6 in drops and not fr.problems
    assert not any(p.bottom.edge == 6 for p, _ in _caps(fr, g.thin, g.ueps_lines, g.veps))
    assert len(fr.patches) <= len(full.patches)
    free = _droppable_cuts(face, m, plan, g)
    for e, ws in drops.items():
        assert ws <= free[e]


def test_wedges_at_a_pole_are_one_cap_per_span(converted):
    """sphere_cut_box.step: the notch's side walls run nearly along u = const in the sphere's
    parameters, and their pcurves' pieces end on slab lines from 0.2014 to 0.22 and from 1.3508
    to 1.3694 (a slab 0.0011 wide). Each slab was a wedge from the pole to the notch, 21 of them
    at each pole, thin and converging (the independent checker matched 336 of their boundary
    samples to the wrong wedge). Below a common v-iso cut the wedges of one knot span are one
    cell now: one wedge per span of the sphere's u (four at each pole)."""
    ins, res, check = converted["sphere_cut_box.step"]
    assert check.ok, check.problems[:3]
    sphere = next(fr for fr in res.faces if fr.pole_caps)
    assert sphere.pole_caps == 2  # one at each pole, over the notched quarter
    for k, v in ((0, -np.pi / 2), (1, np.pi / 2)):
        wedges = [p for p in sphere.patches for side in (p.bottom, p.top)
                  if side.degenerate and abs(float(side.H[0, 1] / side.H[0, 2]) - v) < 1e-9]
        assert len(wedges) == 4, k
        widths = sorted(float(np.ptp(p.bottom.H[:, 0] / p.bottom.H[:, 2])) for p in wedges)
        assert widths == pytest.approx([np.pi / 2] * 4)


def _dip(t0: float, a: float) -> np.ndarray:
    """A quadratic piece running in u from 0 to 1 with v = a (t - t0)^2: lowest at t = t0."""
    v = [a * t0 * t0, a * t0 * (t0 - 1.0), a * (1.0 - t0) ** 2]
    return np.array([[0.0, v[0], 1.0], [0.5, v[1], 1.0], [1.0, v[2], 1.0]])


@pytest.mark.parametrize("t0", [0.999, 0.001])
def test_an_extremum_that_turns_back_by_noise_before_an_end_is_no_cut(t0):
    """fusee face 44: edge 253 runs nearly along v = const and dips 1.4e-11 in v 1e-8 in u before
    its end (the face's corner); cut there, a strip 6.5e-6 wide and 25.8 long. An extremum whose
    value differs from the nearer end's by at most the noise threshold, with no extremum between,
    is no cut; a deeper one, or one well inside the piece, is."""
    from watertight_cli.untrim import _extrema

    H = _dip(t0, 1e-6)  # comes back by 1e-12 between the dip and the end
    assert _extrema(H, 1, 1e-11) == []
    (r,) = _extrema(H, 1, 1e-13)
    assert r == pytest.approx(t0, abs=1e-9)
    (r,) = _extrema(_dip(0.5, 1e-6), 1, 1e-11)  # comes back by 2.5e-7 to either end
    assert r == pytest.approx(0.5, abs=1e-9)
    assert _extrema(_dip(0.5, 1e-6), 0, 1e-11) == []  # u is monotone
