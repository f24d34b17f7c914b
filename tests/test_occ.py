"""Reading, extraction to arrays, round trips and writing through OCP."""

from __future__ import annotations

import hashlib
import os

import numpy as np
import pytest

from watertight_cli.errors import InputError, OutputError
from watertight_cli.inspect import inspect, trimmed

from .conftest import fixture_models, fixture_path


@pytest.fixture(scope="module")
def loft(tol):
    return inspect(str(fixture_path("loft_minus_cylinder.step")), tol)


def test_every_fixture_reads_and_measures(tol):
    """The array model describes the same boundaries as the kernel, edge by edge, within 1e-9 x diag.

    Catches conversions that change a parameterization (seams, angular surfaces, periodic
    B-splines used past their first period, pcurves past their surface's knot range).
    """
    for name in fixture_models():
        ins = inspect(str(fixture_path(name)), tol)
        assert ins.model.faces, name
        kernel = {g.edge: g.gap for g in ins.gaps}
        worst = max((abs(g.gap - kernel[g.edge]) for g in ins.array_gaps), default=0.0)
        assert worst <= 1e-9 * ins.model.diagonal, (name, worst)


def test_surface_round_trip(loft):
    """arrays -> Geom_BSplineSurface -> arrays reproduces the surface to 1e-12."""
    from watertight_cli.occ.extract import surface_arrays, surface_from_arrays

    for face in loft.model.faces:
        s = face.surface
        back = surface_arrays(surface_from_arrays(s))
        assert np.array_equal(back.uknots, s.uknots) and np.array_equal(back.vknots, s.vknots)
        u0, u1, v0, v1 = s.domain
        g = np.random.default_rng(0).random((200, 2)) * [u1 - u0, v1 - v0] + [u0, v0]
        scale = np.abs(s.poles).max()
        assert np.abs(back.evaluate(g) - s.evaluate(g)).max() <= 1e-12 * scale
        # and the arrays evaluate like the kernel does
        geom = surface_from_arrays(s)
        kernel = np.array([geom.Value(u, v).Coord() for u, v in g])
        assert np.abs(kernel - s.evaluate(g)).max() <= 1e-12 * scale


def test_curve_round_trip(loft):
    from watertight_cli.occ.extract import curve_arrays, curve_from_arrays

    for e in loft.model.edges:
        if e.curve is None:
            continue
        geom = curve_from_arrays(e.curve)
        back = curve_arrays(geom)
        t = np.linspace(e.first, e.last, 50)
        kernel = np.array([geom.Value(x).Coord() for x in t])
        assert np.abs(kernel - e.curve.evaluate(t)).max() <= 1e-12 * max(1.0, np.abs(e.curve.poles).max())
        assert np.allclose(back.poles, e.curve.poles, rtol=0, atol=0)


def test_intersection_pcurves_are_high_degree(loft):
    """The loft/cylinder intersection gives the degree-8 pcurves stage 1 must handle."""
    degrees = [ce.pcurve.degree for f in loft.model.faces for lp in f.loops for ce in lp.coedges
               if f.surface_type == "BSpline" and ce.pcurve is not None]
    assert max(degrees) >= 6


def test_topology_of_fixtures(tol):
    sphere = inspect(str(fixture_path("sphere.step")), tol).model
    assert sum(e.degenerate for e in sphere.edges) == 2  # two poles
    assert sum(e.seam for e in sphere.edges) == 1
    assert not trimmed(sphere.faces[0])  # a full sphere is its own parameter rectangle
    two = inspect(str(fixture_path("two_solids.step")), tol).model
    assert two.solids == 2
    # two box faces with the hole, the pin's two round caps; rectangles and cylinders are not
    assert sum(trimmed(f) for f in two.faces) == 4
    holes = inspect(str(fixture_path("plate_with_holes.step")), tol).model
    assert max(len(f.loops) for f in holes.faces) >= 3
    sheet = inspect(str(fixture_path("open_sheet.step")), tol).model
    assert sheet.solids == 0 and sum(e.uses == 1 for e in sheet.edges if not e.degenerate) == 6


def test_unconnected_iges_is_sewn(tol):
    ins = inspect(str(fixture_path("open_sheet_144.igs")), tol)
    s = ins.model.sewing
    assert s is not None
    assert s.free_edges_before == 8 and s.free_edges_after == 6  # the shared edge is recovered
    assert s.max_join_distance < 1e-9 * ins.model.diagonal


def test_gaps_agree_with_arrays_on_bspline_faces(loft):
    """Kernel samples and array samples measure the same boundary geometry (within conversion)."""
    kernel = max(g.gap for g in loft.gaps)
    arrays = max(g.gap for g in loft.array_gaps)
    assert arrays <= 2 * kernel + 1e-9 * loft.model.diagonal


def test_write_is_atomic_and_deterministic(tmp_path):
    from watertight_cli.occ.io import read_shape, write_shape

    shape = read_shape(fixture_path("loft_minus_cylinder.step")).shape
    digests = []
    for sub in ("one", "two"):
        (tmp_path / sub).mkdir()
        write_shape(shape, tmp_path / sub / "a.step")
        digests.append(hashlib.sha256((tmp_path / sub / "a.step").read_bytes()).hexdigest())
        assert os.listdir(tmp_path / sub) == ["a.step"]  # no temp files left behind
    assert digests[0] == digests[1]
    assert b"FILE_NAME('a.step'" in (tmp_path / "one" / "a.step").read_bytes()
    write_shape(shape, tmp_path / "a.step")
    write_shape(shape, tmp_path / "b.step")
    write_shape(shape, tmp_path / "c.igs")
    assert read_shape(tmp_path / "c.igs").shape is not None
    with pytest.raises(OutputError, match="exists"):
        write_shape(shape, tmp_path / "a.step", overwrite=False)
    with pytest.raises(OutputError, match="unknown file type"):
        write_shape(shape, tmp_path / "d.obj")
    assert sorted(os.listdir(tmp_path)) == ["a.step", "b.step", "c.igs", "one", "two"]


def test_iges_output_carries_no_time_stamp_or_login_name(tmp_path):
    """OCCT stamps an IGES global section with the time of writing and the user's login name; two
    writes a second apart differed (I6). Both dates are a fixed stamp and the author is empty."""
    import getpass
    import time

    from watertight_cli.occ.io import IGES_STAMP, read_shape, write_shape

    shape = read_shape(fixture_path("loft_minus_cylinder.igs")).shape
    write_shape(shape, tmp_path / "a.igs")
    time.sleep(1.1)
    write_shape(shape, tmp_path / "b.igs")
    data = (tmp_path / "a.igs").read_bytes()
    assert data == (tmp_path / "b.igs").read_bytes()
    gsec = b"".join(line[:72] for line in data.splitlines() if line[72:73] == b"G")
    assert gsec.count(b"15H" + IGES_STAMP.encode()) == 2
    assert time.strftime("%Y%m%d").encode() not in gsec
    assert b"H" + getpass.getuser().encode() + b"," not in gsec


def test_iges_keeps_reals_to_fourteen_digits(tmp_path):
    """OCCT's IGES writer rounds to 10 digits by default: shared rows then read back 1.6e-8 apart."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
    from OCP.Geom import Geom_BezierSurface
    from OCP.gp import gp_Pnt
    from OCP.TColgp import TColgp_Array2OfPnt
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from watertight_cli.occ.io import read_shape, write_shape

    rng = np.random.default_rng(3)
    xyz = rng.normal(size=(4, 4, 3)) * 10.0 ** rng.integers(-3, 3, size=(4, 4, 3))
    xyz[..., 0] += np.arange(4)[:, None] * 20.0
    xyz[..., 1] += np.arange(4)[None, :] * 20.0
    xyz[0, 0] = (-6.661338147751e-16, 1e-5 / 3, 0.0)  # long negative numbers and tiny ones
    poles = TColgp_Array2OfPnt(1, 4, 1, 4)
    for i in range(4):
        for j in range(4):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*map(float, xyz[i, j])))
    surface = Geom_BezierSurface(poles)
    write_shape(BRepBuilderAPI_MakeFace(surface, 1e-7).Face(), tmp_path / "f.igs")
    back = read_shape(tmp_path / "f.igs").shape
    face = TopoDS.Face_s(TopExp_Explorer(back, TopAbs_FACE).Current())
    read = BRep_Tool.Surface_s(face)
    worst = 0.0
    for u in np.linspace(0.0, 1.0, 7):
        for v in np.linspace(0.0, 1.0, 7):
            a, b = surface.Value(u, v), read.Value(u, v)
            worst = max(worst, a.Distance(b))
    assert worst <= 1e-12 * 60.0


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    from watertight_cli.occ import io

    shape = io.read_shape(fixture_path("sphere.step")).shape

    def boom(*a, **k):
        raise OutputError(tmp_path / "x.step", "simulated failure")

    monkeypatch.setattr(io, "_normalise_header", boom)
    with pytest.raises(OutputError):
        io.write_shape(shape, tmp_path / "x.step")
    assert os.listdir(tmp_path) == []


def test_input_never_modified(tol, tmp_path):
    src = fixture_path("filleted_freeform.step")
    before = hashlib.sha256(src.read_bytes()).hexdigest()
    inspect(str(src), tol)
    assert hashlib.sha256(src.read_bytes()).hexdigest() == before


def test_missing_input_raises_domain_error(tmp_path, tol):
    with pytest.raises(InputError, match="no such file"):
        inspect(str(tmp_path / "x.stp"), tol)


def test_an_edge_off_its_side_within_tolerance_reads_back_untrimmed(tmp_path, tol):
    """An edge whose 3D curve bows 3e-7 off its face's side (its tolerance covers that) keeps the
    side's straight pcurve through a write and a read: the file declares the largest vertex
    tolerance as its uncertainty. With OCCT's default (1e-7) the reader projected fusee's 3D curve
    at a cusp again, the new pcurve left [0, 1]^2 by 2.4e-8 and the face read back trimmed. This
    small case reads back untrimmed either way (the projection lands on the side), so the figure
    written is checked too."""
    from OCP.BRep import BRep_Builder, BRep_Tool
    from OCP.Geom import Geom_BezierCurve
    from OCP.gp import gp_Pnt
    from OCP.TColgp import TColgp_Array1OfPnt
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_VERTEX
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from watertight_cli.occ.build import patch_face
    from watertight_cli.occ.io import write_shape

    u, v = np.meshgrid(np.linspace(0, 10, 3), np.linspace(0, 10, 3), indexing="ij")
    face = patch_face(np.stack([u, v, 0.01 * u * v], axis=-1), False, False)
    B = BRep_Builder()
    ex = TopExp_Explorer(face, TopAbs_EDGE)
    while ex.More():  # bow the side u = 0 (x = 0) outwards in the face's plane, ends kept
        edge = TopoDS.Edge_s(ex.Current())
        curve = BRep_Tool.Curve_s(edge, 0.0, 0.0)
        if abs(curve.Value(0.0).X()) < 1e-12 and abs(curve.Value(1.0).X()) < 1e-12:
            poles = TColgp_Array1OfPnt(1, 3)
            for i, (a, b) in enumerate(((0.0, 0.0), (-6e-7, 5.0), (0.0, 10.0))):
                poles.SetValue(i + 1, gp_Pnt(a, b, 0.0))
            B.UpdateEdge(edge, Geom_BezierCurve(poles), 4e-7)
            vx = TopExp_Explorer(edge, TopAbs_VERTEX)
            while vx.More():
                B.UpdateVertex(TopoDS.Vertex_s(vx.Current()), 4e-7)
                vx.Next()
        ex.Next()
    write_shape(face, tmp_path / "f.step")
    back = inspect(str(tmp_path / "f.step"), tol, array_gaps=False, kernel_tracks=False)
    assert len(back.model.faces) == 1
    assert not trimmed(back.model.faces[0]), back.model.faces[0].uv_bounds
    assert b"LENGTH_MEASURE(4.E-07)" in (tmp_path / "f.step").read_bytes()


def test_a_read_without_healing_reads_the_file_as_written_and_leaves_later_reads_healed(tol):
    """``heal=False`` (the read-back of a written file) switches the STEP reader's shape healing
    off: sphere_cut_box.step, which healing changes (it adds two edges and moves the largest gap
    from 5.3e-8 to 2.3e-6), reads as written. A healed read after it is the same as before it (the
    IGES reader's healing parameters outlive the reader, so IGES keeps healing either way)."""

    def measured(path, heal=True):
        ins = inspect(str(path), tol, array_gaps=False, kernel_tracks=False, heal=heal)
        return len(ins.model.edges), max(g.gap for g in ins.gaps)

    step, iges = fixture_path("sphere_cut_box.step"), fixture_path("loft_minus_cylinder.igs")
    healed, healed_iges = measured(step), measured(iges)
    raw = measured(step, heal=False)
    assert raw[0] < healed[0] and raw[1] < healed[1] / 10, (raw, healed)
    assert measured(iges, heal=False) == healed_iges
    assert measured(step) == healed and measured(iges) == healed_iges


def test_knots_the_splines_do_not_break_at_are_dropped_on_reading(tol):
    """bspline_boolean's edges carry the union of their faces' knots: 162 interior knots, of which
    only 106 are breaks. The model keeps the breaks only (and the kernel check above holds)."""
    m = inspect(str(fixture_path("bspline_boolean.step")), tol).model
    eps = tol.knot_rel * m.diagonal
    inner = 0
    for e in m.edges:
        if e.curve is None:
            continue
        assert e.curve.merged(eps) is e.curve  # nothing left to drop
        c = e.curve
        inner += len(np.unique(c.knots[c.degree + 1:len(c.knots) - c.degree - 1]))
    assert inner == 106
    for f in m.faces:
        assert f.surface.merged(eps) is f.surface


def test_a_rational_surface_keeps_its_shape_without_inserted_knots():
    from watertight_cli.core.bspline import insert_knot
    from watertight_cli.model import BSplineSurface

    rng = np.random.default_rng(3)
    p, q = 2, 3
    uk = np.array([0, 0, 0, 1, 1, 1], float)
    vk = np.array([0, 0, 0, 0, 0.5, 1, 1, 1, 1], float)
    poles = rng.normal(size=(3, 5, 3)) * 10
    w = rng.uniform(0.5, 2, (3, 5))
    H = np.concatenate([poles * w[..., None], w[..., None]], axis=-1)
    uk2, H2 = insert_knot(uk, p, H, 0.3, 1)
    vk2, H3 = insert_knot(vk, q, np.swapaxes(H2, 0, 1), 0.8, 2)
    H3 = np.swapaxes(H3, 0, 1)
    s = BSplineSurface(p, q, uk2, vk2, H3[..., :3] / H3[..., 3:], H3[..., 3])
    m = s.merged(1e-10)
    assert set(np.unique(m.uknots)) == {0.0, 1.0} and set(np.unique(m.vknots)) == {0.0, 0.5, 1.0}
    g = rng.random((300, 2))
    assert np.abs(m.evaluate(g) - s.evaluate(g)).max() <= 1e-10
    assert m.merged(1e-10) is m
