"""Wrap cells (``watertight_cli.wrap``): no slab line through the u-extremum of a trimming curve."""

from __future__ import annotations

import numpy as np
import pytest

from watertight_cli.tolerances import Tolerances
from watertight_cli.untrim import _FaceGeometry, untrim
from watertight_cli.wrap import _inside, wrap_sites

from .conftest import fixture_path

TOL = Tolerances(wrap_tips=True)


def _corner_angles(p) -> list[float]:
    """Degrees between the two sides of a patch at each corner (3D tangents from the control net;
    corners where a side collapses are skipped)."""
    X = p.ctrl[..., :3] / p.ctrl[..., 3:4] if p.rational else p.ctrl
    out = []
    for i, j, di, dj in ((0, 0, 1, 1), (-1, 0, -1, 1), (0, -1, 1, -1), (-1, -1, -1, -1)):
        a, b = X[i + di, j] - X[i, j], X[i, j + dj] - X[i, j]
        na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
        if na > 1e-12 and nb > 1e-12:
            out.append(float(np.degrees(np.arccos(np.clip(abs(a @ b) / (na * nb), 0.0, 1.0)))))
    return out


@pytest.fixture(scope="module")
def plate():
    from watertight_cli.inspect import inspect

    ins = inspect(str(fixture_path("plate_with_holes.step")), TOL)
    return ins.model


def test_every_hole_tip_of_the_plate_is_a_site(plate):
    """The plate's top and bottom faces have three round holes each. Every hole has two u-extrema,
    one inside its circle's edge and one at the circle's only vertex, and the face lies beyond both:
    six sites per face, each tip at its loop's least or greatest u."""
    holed = [f for f in plate.faces if len(f.loops) > 1]
    assert len(holed) == 2
    for face in holed:
        g = _FaceGeometry(face, plate.diagonal, TOL)
        sites = wrap_sites(face, plate, g)
        assert len(sites) == 2 * (len(face.loops) - 1)
        inner = [lp for lp in face.loops if not lp.outer]
        for intervals, tip in sites:
            (e, _, _), *_ = intervals
            loop = next(lp for lp in inner if any(ce.edge == e for ce in lp.coedges))
            u = np.concatenate([ce.pcurve.evaluate(np.linspace(ce.first, ce.last, 2001))[:, 0]
                                for ce in loop.coedges])
            assert min(abs(tip[0] - u.min()), abs(tip[0] - u.max())) <= 1e-6 * np.ptp(u)


def test_no_corner_of_zero_angle_beside_the_holes(plate):
    """Before the wraps, the slab line through each hole's u-extremum was tangent to the hole, and
    the cells beyond it had corners of 0 degrees (26 patches of the plate under 1 degree, the least
    exactly 0). With the tips wrapped, every corner of the holed faces' patches is wider than 5,
    except at a tip that lies on a knot line of the surface (one hole's rightmost point lies on the
    u-knot 0.747774): the cells there must end on the knot line, which is tangent to the hole, so
    that tip is not wrapped."""
    model = plate
    res = untrim(_copy(model), TOL)
    holed = [f.index for f in model.faces if len(f.loops) > 1]
    for i in holed:
        g = _FaceGeometry(model.faces[i], model.diagonal, TOL)
        tips = np.array([tip for _, tip in wrap_sites(model.faces[i], model, g)])
        on_knot = np.array([np.abs(g.ub[1:-1] - u).min() <= 1e-9 for u in tips[:, 0]])
        assert on_knot.sum() == 1
        assert res.faces[i].wraps == len(tips) - 1
        for p in res.faces[i].patches:
            if min(_corner_angles(p), default=90.0) > 5.0:
                continue
            corners = np.array([H[k, :2] / H[k, 2] for H in (p.bottom.H, p.top.H) for k in (0, -1)])
            assert np.linalg.norm(corners[:, None] - tips[on_knot][None], axis=2).min() <= 1e-9


def _copy(model):
    """untrim may replace faces of the model it is given (turned faces): work on a copy."""
    from dataclasses import replace

    return replace(model, faces=list(model.faces))


def test_inside_counts_the_crossings_of_a_ray():
    """The unit square with a square hole [0.4, 0.6]^2, as straight homogeneous pieces."""
    def loop(pts):
        return [np.array([[*a, 1.0], [*b, 1.0]]) for a, b in zip(pts, pts[1:] + pts[:1], strict=True)]

    spans = loop([(0, 0), (1, 0), (1, 1), (0, 1)]) + loop([(0.4, 0.4), (0.4, 0.6), (0.6, 0.6), (0.6, 0.4)])
    for toward in (-1.0, 1.0):
        assert _inside(spans, np.array([0.2, 0.5]), toward)
        assert _inside(spans, np.array([0.8, 0.45]), toward)
        assert not _inside(spans, np.array([0.5, 0.5]), toward)
        assert not _inside(spans, np.array([1.2, 0.5]), toward)


def test_wrap_tips_is_the_default_of_convert(tmp_path):
    """The wraps are on by default and ``--no-wrap-tips`` reaches stage 1 through the CLI: the plate
    converts with every invariant both ways, with more patches when wrapped (the turned cells and
    the notches' cuts)."""
    import json

    from click.testing import CliRunner

    from watertight_cli.cli import main

    counts = []
    for extra in (["--no-wrap-tips"], []):
        out = tmp_path / f"o{len(extra)}.step"
        args = ["convert", str(fixture_path("plate_with_holes.step")), str(out), "--json", *extra]
        res = CliRunner().invoke(main, args)
        assert res.exit_code == 0, res.output
        rep = json.loads(res.stdout)
        assert all(rep["invariants"].values())
        assert (rep["wraps"] > 0) is not bool(extra)  # the report counts them
        counts.append(rep["patches_out"])
    assert counts[1] > counts[0]
