"""From an OCCT shape to the array model (``watertight_cli.model``), and back for surfaces.

Steps:
1. sew when the faces are not connected (IGES 144 trimmed surfaces, STEP surface models);
2. convert every face to B-spline geometry with ``BRepBuilderAPI_NurbsConvert`` (exact for
   analytic surfaces, surfaces of revolution and of extrusion; it keeps 3D curves and pcurves
   same-parameter) and approximate what stays non-B-spline (offset surfaces), recording the bound;
3. read surfaces, pcurves, 3D curves, loops and incidence into numpy arrays.
"""

from __future__ import annotations

import math

import numpy as np
from OCP.Bnd import Bnd_Box
from OCP.BRep import BRep_Tool
from OCP.BRepBndLib import BRepBndLib
from OCP.BRepBuilderAPI import BRepBuilderAPI_NurbsConvert, BRepBuilderAPI_Sewing
from OCP.BRepTools import BRepTools, BRepTools_WireExplorer
from OCP.Geom import (
    Geom_BSplineCurve,
    Geom_BSplineSurface,
    Geom_RectangularTrimmedSurface,
    Geom_TrimmedCurve,
)
from OCP.Geom2d import Geom2d_BSplineCurve, Geom2d_TrimmedCurve
from OCP.Geom2dConvert import Geom2dConvert
from OCP.GeomAbs import GeomAbs_C2
from OCP.GeomConvert import GeomConvert, GeomConvert_ApproxSurface
from OCP.TColgp import TColgp_Array1OfPnt, TColgp_Array2OfPnt
from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal, TColStd_Array2OfReal
from OCP.TopAbs import (
    TopAbs_EDGE,
    TopAbs_FACE,
    TopAbs_REVERSED,
    TopAbs_SHELL,
    TopAbs_SOLID,
    TopAbs_VERTEX,
    TopAbs_WIRE,
)
from OCP.TopExp import TopExp, TopExp_Explorer
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS, TopoDS_Shape
from OCP.TopTools import TopTools_IndexedDataMapOfShapeListOfShape, TopTools_IndexedMapOfShape

from ..errors import InputError, KernelError
from ..model import (
    BSplineCurve,
    BSplineSurface,
    Coedge,
    Edge,
    Face,
    Loop,
    Model,
    SewingInfo,
)
from ..tolerances import Tolerances
from .io import ReadResult, quiet

# ---------------------------------------------------------------------------------------------
# small helpers


def indexed(shape: TopoDS_Shape, kind) -> TopTools_IndexedMapOfShape:
    m = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, kind, m)
    return m


def count(shape: TopoDS_Shape, kind) -> int:
    return indexed(shape, kind).Extent()


def diagonal(shape: TopoDS_Shape) -> float:
    box = Bnd_Box()
    BRepBndLib.Add_s(shape, box)
    if box.IsVoid():
        return 0.0
    x0, y0, z0, x1, y1, z1 = box.Get()
    return math.dist((x0, y0, z0), (x1, y1, z1))


def edge_face_map(shape: TopoDS_Shape) -> TopTools_IndexedDataMapOfShapeListOfShape:
    m = TopTools_IndexedDataMapOfShapeListOfShape()
    TopExp.MapShapesAndAncestors_s(shape, TopAbs_EDGE, TopAbs_FACE, m)
    return m


def free_edge_count(shape: TopoDS_Shape) -> int:
    """Edges used by exactly one face side (seams count as two uses)."""
    m = edge_face_map(shape)
    free = 0
    for i in range(1, m.Extent() + 1):
        e = TopoDS.Edge_s(m.FindKey(i))
        if BRep_Tool.Degenerated_s(e):
            continue
        faces = _unique_faces(m.FindFromIndex(i))
        uses = len(faces) + (1 if any(BRep_Tool.IsClosed_s(e, f) for f in faces) else 0)
        free += uses == 1
    return free


def _unique_faces(lst) -> list:
    out = []
    for f in lst:
        f = TopoDS.Face_s(f)
        if not any(f.IsSame(g) for g in out):
            out.append(f)
    return out


def surface_type_name(face) -> str:
    s = BRep_Tool.Surface_s(face)
    while isinstance(s, Geom_RectangularTrimmedSurface):
        s = s.BasisSurface()
    name = type(s).__name__
    return name.removeprefix("Geom_").removesuffix("Surface") or name


# ---------------------------------------------------------------------------------------------
# kernel objects -> arrays


def _arr1(a: TColStd_Array1OfReal) -> np.ndarray:
    return np.array([a.Value(i) for i in range(a.Lower(), a.Upper() + 1)], dtype=float)


def surface_arrays(s: Geom_BSplineSurface) -> BSplineSurface:
    """A Geom_BSplineSurface (made non-periodic on a copy if needed) as arrays."""
    if s.IsUPeriodic() or s.IsVPeriodic():
        s = s.Copy()
        if s.IsUPeriodic():
            s.SetUNotPeriodic()
        if s.IsVPeriodic():
            s.SetVNotPeriodic()
    nu, nv = s.NbUPoles(), s.NbVPoles()
    poles = np.empty((nu, nv, 3))
    for i in range(1, nu + 1):
        for j in range(1, nv + 1):
            poles[i - 1, j - 1] = s.Pole(i, j).Coord()
    weights = None
    if s.IsURational() or s.IsVRational():
        weights = np.empty((nu, nv))
        for i in range(1, nu + 1):
            for j in range(1, nv + 1):
                weights[i - 1, j - 1] = s.Weight(i, j)
    uk = TColStd_Array1OfReal(1, nu + s.UDegree() + 1)
    vk = TColStd_Array1OfReal(1, nv + s.VDegree() + 1)
    s.UKnotSequence(uk)
    s.VKnotSequence(vk)
    return BSplineSurface(s.UDegree(), s.VDegree(), _arr1(uk), _arr1(vk), poles, weights)


def curve_arrays(c) -> BSplineCurve:
    """A Geom_BSplineCurve or Geom2d_BSplineCurve (made non-periodic on a copy) as arrays."""
    if c.IsPeriodic():
        c = c.Copy()
        c.SetNotPeriodic()
    n = c.NbPoles()
    poles = np.array([c.Pole(i).Coord() for i in range(1, n + 1)], dtype=float)
    weights = None
    if c.IsRational():
        weights = np.array([c.Weight(i) for i in range(1, n + 1)], dtype=float)
    k = TColStd_Array1OfReal(1, n + c.Degree() + 1)
    c.KnotSequence(k)
    return BSplineCurve(c.Degree(), _arr1(k), poles, weights)


def _bspline_3d(curve, first: float, last: float) -> Geom_BSplineCurve:
    if isinstance(curve, Geom_BSplineCurve):
        return curve
    return GeomConvert.CurveToBSplineCurve_s(Geom_TrimmedCurve(curve, first, last))


def _bspline_2d(curve, first: float, last: float) -> Geom2d_BSplineCurve:
    if isinstance(curve, Geom2d_BSplineCurve):
        return curve
    return Geom2dConvert.CurveToBSplineCurve_s(Geom2d_TrimmedCurve(curve, first, last))


# ---------------------------------------------------------------------------------------------
# arrays -> kernel objects (round trip, and later the build step)


def surface_from_arrays(s: BSplineSurface) -> Geom_BSplineSurface:
    """Arrays back to a Geom_BSplineSurface (flat knots are compressed to knots + multiplicities)."""
    nu, nv = s.poles.shape[:2]
    poles = TColgp_Array2OfPnt(1, nu, 1, nv)
    from OCP.gp import gp_Pnt

    for i in range(nu):
        for j in range(nv):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*map(float, s.poles[i, j])))
    uk, um = _compress(s.uknots)
    vk, vm = _compress(s.vknots)
    if s.weights is None:
        return Geom_BSplineSurface(poles, uk, vk, um, vm, s.udegree, s.vdegree)
    w = TColStd_Array2OfReal(1, nu, 1, nv)
    for i in range(nu):
        for j in range(nv):
            w.SetValue(i + 1, j + 1, float(s.weights[i, j]))
    return Geom_BSplineSurface(poles, w, uk, vk, um, vm, s.udegree, s.vdegree)


def curve_from_arrays(c: BSplineCurve) -> Geom_BSplineCurve:
    from OCP.gp import gp_Pnt

    pts = TColgp_Array1OfPnt(1, len(c.poles))
    for i, p in enumerate(c.poles):
        pts.SetValue(i + 1, gp_Pnt(*map(float, p)))
    k, m = _compress(c.knots)
    if c.weights is None:
        return Geom_BSplineCurve(pts, k, m, c.degree)
    w = TColStd_Array1OfReal(1, len(c.weights))
    for i, x in enumerate(c.weights):
        w.SetValue(i + 1, float(x))
    return Geom_BSplineCurve(pts, w, k, m, c.degree)


def _compress(flat: np.ndarray) -> tuple[TColStd_Array1OfReal, TColStd_Array1OfInteger]:
    vals, mults = [], []
    for x in flat:
        if vals and x == vals[-1]:
            mults[-1] += 1
        else:
            vals.append(float(x))
            mults.append(1)
    k = TColStd_Array1OfReal(1, len(vals))
    m = TColStd_Array1OfInteger(1, len(vals))
    for i, (x, n) in enumerate(zip(vals, mults, strict=True)):
        k.SetValue(i + 1, x)
        m.SetValue(i + 1, n)
    return k, m


# ---------------------------------------------------------------------------------------------
# sewing


def needs_sewing(shape: TopoDS_Shape) -> bool:
    """True when the faces are not connected: several faces and not one edge shared by two."""
    nfaces = count(shape, TopAbs_FACE)
    if nfaces < 2:
        return False
    m = edge_face_map(shape)
    for i in range(1, m.Extent() + 1):
        if len(_unique_faces(m.FindFromIndex(i))) >= 2:
            return False
    return True


def sew(shape: TopoDS_Shape, diag: float, tol: Tolerances, path: str) -> tuple[TopoDS_Shape, SewingInfo]:
    """Sew unconnected faces at the smallest tolerance that recovers their adjacency.

    Tolerances are tried by decades from 1e-7 x diagonal up to ``tol.sew_max_rel`` x diagonal.
    Adjacency that exists in the design closes at one tolerance and then stays closed over the
    following decades (a plateau of the free-edge count); the smallest tolerance of the first
    plateau is kept. Going further would start joining boundaries that are meant to be apart.
    """
    before = free_edge_count(shape)
    limit = tol.sew_max_rel * diag
    t = 1e-7 * diag
    best = None
    while t <= limit * (1 + 1e-12):
        sewer = BRepBuilderAPI_Sewing(t)
        sewer.Load(shape)
        with quiet():
            sewer.Perform()
        result = sewer.SewedShape()
        if result is None or result.IsNull():
            raise KernelError(f"{path}: sewing failed at tolerance {t:.3g}")
        free = free_edge_count(result)
        if best is not None and free == best[1] and free < before:
            break  # a plateau: keep the smaller tolerance
        if best is None or free < best[1]:
            best = (result, free, t)
        if free == 0:
            break
        t *= 10.0
    result, free, t = best
    info = SewingInfo(tolerance=t, free_edges_before=before, free_edges_after=free,
                      edges_joined=(before - free) // 2, max_join_distance=0.0)
    return result, info


# ---------------------------------------------------------------------------------------------
# the model


def _to_nurbs(shape: TopoDS_Shape, path: str) -> tuple[TopoDS_Shape, BRepBuilderAPI_NurbsConvert]:
    with quiet():
        conv = BRepBuilderAPI_NurbsConvert(shape, True)
    if not conv.IsDone():
        raise KernelError(f"{path}: conversion to NURBS failed")
    return conv.Shape(), conv


def _approximate_surface(surf, bounds, tolerance: float) -> tuple[Geom_BSplineSurface, float]:
    """Approximate a non-B-spline surface (offset surfaces) over the face's domain."""
    u0, u1, v0, v1 = bounds
    trimmed = Geom_RectangularTrimmedSurface(surf, u0, u1, v0, v1)
    approx = GeomConvert_ApproxSurface(trimmed, tolerance, GeomAbs_C2, GeomAbs_C2, 9, 9, 200, 0)
    if not approx.HasResult():
        raise KernelError("surface approximation failed")
    return approx.Surface(), float(approx.MaxError())


def prepare(read: ReadResult, path: str, tol: Tolerances) -> tuple[TopoDS_Shape, float, SewingInfo | None]:
    """The shape the pipeline works on: the input, sewn when its faces are not connected."""
    shape = read.shape
    if count(shape, TopAbs_FACE) == 0:
        raise InputError(path, "the file holds no faces (wireframe or empty model)")
    diag = diagonal(shape)
    if not diag > 0:
        raise InputError(path, "the model has no extent (all geometry at one point)")
    sewing = None
    if needs_sewing(shape):
        shape, sewing = sew(shape, diag, tol, path)
    return shape, diag, sewing


def sample_tracks(shape: TopoDS_Shape, k: int) -> dict[int, tuple[np.ndarray | None, list]]:
    """The input's own boundary geometry, sampled with the kernel at k equal edge parameters.

    Returns, per non-degenerate edge index (the order of ``indexed(shape, TopAbs_EDGE)``):
    (C(w) as (k, 3) or None, [(face index, S_f(pc_f(w)) as (k, 3)), ...]) with seams giving two
    tracks for their face. These arrays feed the pure-numpy gap measurement in
    ``watertight_cli.gaps``: the report measures the input itself, not a conversion of it.
    """
    from OCP.BRepAdaptor import BRepAdaptor_Curve

    fmap = indexed(shape, TopAbs_FACE)
    emap = indexed(shape, TopAbs_EDGE)
    e2f = edge_face_map(shape)
    out = {}
    for ei in range(1, emap.Extent() + 1):
        e = TopoDS.Edge_s(emap.FindKey(ei))
        if BRep_Tool.Degenerated_s(e):
            continue
        a, b = BRep_Tool.Range_s(e)
        ws = np.linspace(a, b, k)
        c3 = BRep_Tool.Curve_s(e, 0.0, 0.0)
        cpts = np.array([c3.Value(w).Coord() for w in ws]) if c3 is not None else None
        tracks = []
        for f in (_unique_faces(e2f.FindFromKey(e)) if e2f.Contains(e) else []):
            fi = fmap.FindIndex(f) - 1
            uses = [e]
            if BRep_Tool.IsClosed_s(e, f):
                uses.append(TopoDS.Edge_s(e.Reversed()))
            for use in uses:
                if BRep_Tool.CurveOnSurface_s(use, f, 0.0, 0.0) is None:
                    continue
                adaptor = BRepAdaptor_Curve(use, f)
                tracks.append((fi, np.array([adaptor.Value(w).Coord() for w in ws])))
        out[ei - 1] = (cpts, tracks)
    return out


def build_model(shape: TopoDS_Shape, read: ReadResult, diag: float, sewing: SewingInfo | None, path: str,
                tol: Tolerances) -> tuple[Model, TopoDS_Shape]:
    """The array model of a prepared shape, plus the NURBS-converted OCCT shape it describes.

    Faces and edges keep the numbering of ``indexed(shape, ...)`` of the prepared shape, so
    ``sample_tracks(shape)`` and the model agree on indices.
    """
    fmap0 = indexed(shape, TopAbs_FACE)
    emap0 = indexed(shape, TopAbs_EDGE)
    types = [surface_type_name(TopoDS.Face_s(fmap0.FindKey(i))) for i in range(1, fmap0.Extent() + 1)]
    conv_shape, conv = _to_nurbs(shape, path)

    fmap = TopTools_IndexedMapOfShape()
    for i in range(1, fmap0.Extent() + 1):
        fmap.Add(conv.ModifiedShape(fmap0.FindKey(i)))
    emap = TopTools_IndexedMapOfShape()
    for i in range(1, emap0.Extent() + 1):
        emap.Add(conv.ModifiedShape(emap0.FindKey(i)))
    if fmap.Extent() != fmap0.Extent() or emap.Extent() != emap0.Extent():
        raise KernelError(f"{path}: conversion to NURBS changed the topology")
    vmap = indexed(conv_shape, TopAbs_VERTEX)
    e2f = edge_face_map(conv_shape)

    vertices = np.array([BRep_Tool.Pnt_s(TopoDS.Vertex_s(vmap.FindKey(i))).Coord()
                         for i in range(1, vmap.Extent() + 1)], dtype=float).reshape(-1, 3)

    faces = [_face(TopoDS.Face_s(fmap.FindKey(fi)), fi - 1, types[fi - 1], emap, diag, tol)
             for fi in range(1, fmap.Extent() + 1)]

    edges: list[Edge] = []
    for ei in range(1, emap.Extent() + 1):
        e = TopoDS.Edge_s(emap.FindKey(ei))
        degenerate = BRep_Tool.Degenerated_s(e)
        first, last = BRep_Tool.Range_s(e)
        curve = None
        if not degenerate:
            c = BRep_Tool.Curve_s(e, 0.0, 0.0)  # the 3-argument form applies the edge's location
            if c is not None:
                curve = curve_arrays(_bspline_3d(c, first, last))
        inc = _unique_faces(e2f.FindFromKey(e)) if e2f.Contains(e) else []
        face_ids = tuple(sorted(fmap.FindIndex(f) - 1 for f in inc))
        seam = any(BRep_Tool.IsClosed_s(e, f) for f in inc)
        ends = (TopExp.FirstVertex_s(e), TopExp.LastVertex_s(e))
        vids = tuple(vmap.FindIndex(v) - 1 if not v.IsNull() else -1 for v in ends)
        edges.append(Edge(ei - 1, curve, first, last, BRep_Tool.Tolerance_s(e), vids, face_ids, seam,
                          degenerate))

    model = Model(path=path, faces=faces, edges=edges, vertices=vertices, diagonal=diag,
                  solids=count(shape, TopAbs_SOLID), shells=count(shape, TopAbs_SHELL),
                  units=read.units, sewing=sewing)
    return model, conv_shape


def _coedge(e, face, emap) -> Coedge:
    first, last = BRep_Tool.Range_s(e, face)
    pc = BRep_Tool.CurveOnSurface_s(e, face, 0.0, 0.0)
    pcurve = curve_arrays(_bspline_2d(pc, first, last)) if pc is not None else None
    return Coedge(edge=emap.FindIndex(e) - 1, reversed=e.Orientation() == TopAbs_REVERSED,
                  pcurve=pcurve, first=first, last=last)


def _face(face, index: int, stype: str, emap, diag: float, tol: Tolerances) -> Face:
    loc = TopLoc_Location()
    surf = BRep_Tool.Surface_s(face, loc)
    while isinstance(surf, Geom_RectangularTrimmedSurface):
        surf = surf.BasisSurface()
    if not loc.IsIdentity():
        surf = surf.Transformed(loc.Transformation())
    bounds = BRepTools.UVBounds_s(face)
    approx = 0.0
    if not isinstance(surf, Geom_BSplineSurface):
        surf, approx = _approximate_surface(surf, bounds, tol.approx_rel * diag)
    arrays = surface_arrays(surf)

    loops = []
    outer = BRepTools.OuterWire_s(face)
    wires = indexed(face, TopAbs_WIRE)
    for wi in range(1, wires.Extent() + 1):
        wire = TopoDS.Wire_s(wires.FindKey(wi))
        coedges = []
        explorer = BRepTools_WireExplorer(wire, face)
        while explorer.More():
            coedges.append(_coedge(explorer.Current(), face, emap))  # oriented as used in this wire
            explorer.Next()
        if not coedges:  # wires the explorer cannot order (rare): fall back to storage order
            exp = TopExp_Explorer(wire, TopAbs_EDGE)
            while exp.More():
                coedges.append(_coedge(TopoDS.Edge_s(exp.Current()), face, emap))
                exp.Next()
        loops.append(Loop(tuple(coedges), outer=not outer.IsNull() and wire.IsSame(outer)))
    loops.sort(key=lambda lp: not lp.outer)
    return Face(index=index, surface=arrays, surface_type=stype,
                reversed=face.Orientation() == TopAbs_REVERSED, loops=tuple(loops),
                uv_bounds=tuple(float(x) for x in bounds), approximation=approx)


__all__ = ["build_model", "surface_arrays", "surface_from_arrays", "curve_arrays", "curve_from_arrays",
           "diagonal", "free_edge_count", "needs_sewing", "prepare", "sample_tracks"]
