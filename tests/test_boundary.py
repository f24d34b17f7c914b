"""The topology-blind boundary gap (``boundary``): synthetic faces, a fixture, and the CLI option."""

import json

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.boundary import boundary_gap, nearest_boundaries
from watertight_cli.cli import main
from watertight_cli.model import BSplineCurve, BSplineSurface, Coedge, Edge, Face, Loop, Model

from .conftest import FIXTURES


def _line(p, q) -> BSplineCurve:
    return BSplineCurve(1, np.array([0.0, 0.0, 1.0, 1.0]), np.array([p, q], dtype=float))


def _quads(corners: list[np.ndarray], diagonal: float = 10.0) -> Model:
    """Bilinear faces from their corner grids ((2, 2, 3): [u][v]), each with its own four edges
    (no two faces share an edge: the measure must not need the topology)."""
    faces, edges = [], []
    sides = (((0, 0), (1, 0)), ((1, 0), (1, 1)), ((1, 1), (0, 1)), ((0, 1), (0, 0)))
    for fi, c in enumerate(corners):
        srf = BSplineSurface(1, 1, np.array([0.0, 0, 1, 1]), np.array([0.0, 0, 1, 1]), np.asarray(c, float))
        coedges = []
        for p, q in sides:
            e = len(edges)
            edges.append(Edge(e, _line(c[p], c[q]), 0.0, 1.0, 1e-7, (0, 0), (fi,), False, False))
            coedges.append(Coedge(e, False, _line(p, q), 0.0, 1.0))
        faces.append(Face(fi, srf, "BSpline", False, (Loop(tuple(coedges), True),), (0.0, 1.0, 0.0, 1.0)))
    return Model("synthetic", faces, edges, np.zeros((1, 3)), diagonal, 0, 1)


def _square(x0: float, z: float = 0.0, dz: float = 0.0) -> np.ndarray:
    """Unit square [x0, x0+1] x [0, 1] at height z, its side x = x0 + 1 raised by dz."""
    return np.array([[[x0, 0, z], [x0, 1, z]], [[x0 + 1, 0, z + dz], [x0 + 1, 1, z + dz]]])


@settings(max_examples=25, deadline=None)
@given(st.floats(1e-6, 5e-6))
def test_a_shifted_neighbour_is_measured_at_its_shift(delta):
    """Two squares side by side, the second lifted by delta: the common side's samples find the
    other face's side delta away; the other sides are free (nothing within 1e-6 of the diagonal)."""
    m = _quads([_square(0.0), _square(1.0, z=delta)], diagonal=100.0)
    g = boundary_gap(m, match_rel=1e-6)
    assert g.samples == 8 * 15
    assert g.unmatched == 6 * 15
    assert g.matched_max == pytest.approx(delta, rel=1e-9, abs=1e-15)
    assert g.over == 30  # both sides of the joint, over 1e-9 of the diagonal


def test_the_nearest_boundary_wins_over_the_nearest_sample():
    """A third face's boundary close beside the joint, made of many short edges (dense samples),
    while the true partner is one long edge: the partner is found, not the third face."""
    strip_w = 2e-5
    long_face = np.array([[[0, 0, 0], [0, 1, 0]], [[8, 0, 0], [8, 1, 0]]], float)  # side y=1, 8 long
    other = np.array([[[0, 1, 0], [0, 2, 0]], [[8, 1, 0], [8, 2, 0]]], float)  # shares y=1
    # short squares whose lower side runs strip_w above y = 1 (a third face's boundary)
    lo, hi = 1 + strip_w, 1 + strip_w + 0.01
    thirds = [np.array([[[x, lo, 0], [x, hi, 0]], [[x + 0.01, lo, 0], [x + 0.01, hi, 0]]])
              for x in np.arange(0, 8, 0.01)]
    m = _quads([long_face, other] + thirds, diagonal=10.0)
    g = boundary_gap(m)
    # the long face's top side: every sample within rounding of the other face's side
    assert g.matched_max < 1e-12  # a third face's side would give strip_w
    # the checker's rule (the curve of the nearest sample) picks the third face here: show it does
    from scipy.spatial import cKDTree
    xs = np.arange(1, 16) / 16 * 8
    dense = np.concatenate([np.c_[np.linspace(0, 8, 272), np.ones(272), np.zeros(272)]]
                           + [np.c_[np.linspace(x, x + 0.01, 272), np.full(272, 1 + strip_w), np.zeros(272)]
                              for x in np.arange(0, 8, 0.01)])
    _, idx = cKDTree(dense).query(np.c_[xs, np.ones(15), np.zeros(15)])
    assert (idx >= 272).any()


def test_a_crowd_nearer_than_the_partner_s_segments_does_not_hide_it():
    """Twenty other faces' sides run 2e-5 to 4e-4 beside a shared side, each with a polyline
    segment centred on the side's middle sample, while the partner's nearest segment centre lies
    0.05 away along it: the 16 nearest segments are all the crowd's. The partner is still found
    (fusee: a point measured 2.25e-4 from its partner's boundary before the lookup asked again)."""
    length = 6.4  # 64 polyline segments of 0.1: the crowd's sides are as long, one length class
    face = np.array([[[0, 0, 0], [0, 1, 0]], [[length, 0, 0], [length, 1, 0]]], float)
    partner = np.array([[[0, -1, 0], [0, 0, 0]], [[length, -1, 0], [length, 0, 0]]], float)
    x0, x1 = -0.05, length - 0.05  # a segment centre at x = 3.2, under the middle sample
    crowd = [np.array([[[x0, -d, 0], [x0, -d - 1, 0]], [[x1, -d, 0], [x1, -d - 1, 0]]])
             for d in 2e-5 * np.arange(1, 21)]
    m = _quads([face, partner] + crowd, diagonal=1000.0)  # match 1e-3: the whole crowd in reach
    pts, faces, dist = nearest_boundaries(m, 15, 1e-3)
    middle = np.flatnonzero((faces == 0) & (np.linalg.norm(pts - [length / 2, 0, 0], axis=1) < 1e-12))
    assert len(middle) == 1
    assert dist[middle[0]] < 1e-12


def test_open_sheet_rim_is_free_and_the_rest_matched():
    from watertight_cli.inspect import inspect
    from watertight_cli.tolerances import Tolerances

    ins = inspect(str(FIXTURES / "open_sheet.step"), Tolerances(), array_gaps=False)
    g = boundary_gap(ins.model)
    assert g.unmatched > 0 and g.unmatched < g.samples
    assert g.matched_max <= 1e-12 * ins.model.diagonal


def test_report_boundary_option_json():
    r = CliRunner().invoke(main, ["report", "--boundary", "--json", "-q", str(FIXTURES / "torus.step")])
    assert r.exit_code == 0, r.output
    b = json.loads(r.stdout)["boundary"]
    assert b["samples"] > 0 and b["unmatched"] == 0
    assert b["gap_relative"] < 1e-9
    assert set(b) >= {"gap", "where", "unmatched", "match_distance", "over_limit", "limit"}
