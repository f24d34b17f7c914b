"""From an OCCT shape to the array model (``watertight_cli.model``), and back for surfaces.

Steps:
1. sew when the faces are not connected (IGES 144 trimmed surfaces, STEP surface models);
2. convert every surface, pcurve and 3D curve to B-spline *in its own parameterization*, so
   that pcurves stay valid on their surfaces and same-parameter with their edges (exact where
   a conversion keeps the parameter, else approximated within ``Tolerances.convert_rel`` with the
   error recorded). ``BRepBuilderAPI_NurbsConvert`` is not used: on OCCT 7.9 it breaks seam
   pcurves (ec_turbine-A: 39 mm) and moves pcurves of revolved faces by up to 1e-4 of the
   diagonal (wing_fuselage: 0.1 mm);
3. read surfaces, pcurves, 3D curves, loops and incidence into numpy arrays.
"""

from __future__ import annotations

import math

import numpy as np
from OCP.Bnd import Bnd_Box
from OCP.BRep import BRep_Tool
from OCP.BRepBndLib import BRepBndLib
from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing
from OCP.BRepTools import BRepTools, BRepTools_WireExplorer
from OCP.Geom import (
    Geom_BSplineCurve,
    Geom_BSplineSurface,
    Geom_RectangularTrimmedSurface,
    Geom_TrimmedCurve,
)
from OCP.Geom2d import Geom2d_BSplineCurve, Geom2d_TrimmedCurve
from OCP.Geom2dConvert import Geom2dConvert, Geom2dConvert_ApproxCurve
from OCP.GeomAbs import GeomAbs_C2
from OCP.GeomConvert import GeomConvert, GeomConvert_ApproxCurve, GeomConvert_ApproxSurface
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
from OCP.TopTools import (
    TopTools_IndexedDataMapOfShapeListOfShape,
    TopTools_IndexedMapOfShape,
    TopTools_ListOfShape,
)

from ..errors import InputError, KernelError
from ..gaps import PER_SPAN, track_params
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


def _members(lst) -> list:
    """The shapes of a TopTools_ListOfShape. Python iteration of an OCP list costs ~0.2 ms (it
    copies), which made edge->face lookups a third of the read-back on models of thousands of
    edges; First/Last cover the usual one or two faces, a copy popped from the front the rest."""
    n = lst.Size()
    if n <= 2:
        return [lst.First(), lst.Last()][2 - n:] if n else []
    rest = TopTools_ListOfShape()
    rest.Assign(lst)
    out = []
    while not rest.IsEmpty():
        out.append(rest.First())
        rest.RemoveFirst()
    return out


def _unique_faces(lst) -> list:
    out = []
    for f in _members(lst):
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


# Conversions keep the kernel's parameterization: pcurves and 3D curves stay same-parameter, and
# pcurves stay valid on converted surfaces. Exact conversions are used where they keep it (lines,
# Bezier, planes, extrusions); conics and elementary surfaces with angular parameters have no
# rational form in their angle, so they are approximated in their own parameterization, with the
# error measured and recorded.

_FIT_DEGREE = 11
_FIT_SEGMENTS = 400


def _keeps_parameter(original, converted, params, tolerance: float) -> bool:
    for w in params:
        if original.Value(*w).Distance(converted.Value(*w)) > tolerance:
            return False
    return True


def _unroll_curve(c, first: float, last: float):
    """A periodic B-spline used past its first period: the same curve segmented to [first, last].

    Unperiodizing alone keeps only the first period; extending its end spans is not the same
    curve. Segmenting by knot insertion is exact.
    """
    if not c.IsPeriodic():
        return c
    a, b = c.FirstParameter(), c.LastParameter()
    eps = 1e-12 * max(1.0, b - a)
    if first >= a - eps and last <= b + eps:
        return c
    c = c.Copy()
    c.Segment(first, last)
    return c


def _unroll_surface(s: Geom_BSplineSurface, bounds) -> Geom_BSplineSurface:
    """The surface analogue of ``_unroll_curve`` for faces that run across a periodic knot range."""
    if not (s.IsUPeriodic() or s.IsVPeriodic()):
        return s
    su0, su1, sv0, sv1 = s.Bounds()
    u0, u1, v0, v1 = bounds
    eu, ev = 1e-12 * max(1.0, su1 - su0), 1e-12 * max(1.0, sv1 - sv0)
    cut_u = s.IsUPeriodic() and (u0 < su0 - eu or u1 > su1 + eu)
    cut_v = s.IsVPeriodic() and (v0 < sv0 - ev or v1 > sv1 + ev)
    if not (cut_u or cut_v):
        return s
    c = s.Copy()
    try:
        c.Segment(u0 if cut_u else su0, u1 if cut_u else su1, v0 if cut_v else sv0, v1 if cut_v else sv1)
    except Exception:  # noqa: BLE001 - Standard_DomainError: bounds past one period
        # bounds past one period: a degenerate face whose two sides coincide, which sewing joined to
        # itself across the closure (its pcurves run to u = 2 on a [0, 1] surface); kept as it is
        return s
    return c


def _curve_bspline(curve, first, last, tolerance, kind, trimmed_type, convert, approx_type):
    """Shared by ``curve_3d`` and ``curve_2d``: keep, convert exactly, or approximate."""
    if isinstance(curve, kind):
        return _unroll_curve(curve, first, last), 0.0
    trimmed = trimmed_type(curve, first, last)
    ws = [(w,) for w in np.linspace(first, last, 13)[1:-1]]
    try:
        exact = convert(trimmed)
        if _keeps_parameter(curve, exact, ws, 1e-3 * tolerance):
            return exact, 0.0
    except Exception:  # noqa: BLE001 - fall through to the approximation
        pass
    approx = approx_type(trimmed, tolerance, GeomAbs_C2, _FIT_SEGMENTS, _FIT_DEGREE)
    if not approx.HasResult():
        raise KernelError(f"cannot convert a {type(curve).__name__} to B-spline")
    return approx.Curve(), float(approx.MaxError())


def curve_3d(curve, first: float, last: float, tolerance: float) -> tuple[Geom_BSplineCurve, float]:
    """A 3D curve as a B-spline in its own parameter on [first, last]; (curve, error bound)."""
    return _curve_bspline(curve, first, last, tolerance, Geom_BSplineCurve, Geom_TrimmedCurve,
                          GeomConvert.CurveToBSplineCurve_s, GeomConvert_ApproxCurve)


def curve_2d(curve, first: float, last: float, tolerance: float) -> tuple[Geom2d_BSplineCurve, float]:
    """A pcurve as a 2D B-spline in its own parameter on [first, last]; (curve, error bound).

    ``tolerance`` is in parameter units.
    """
    return _curve_bspline(curve, first, last, tolerance, Geom2d_BSplineCurve, Geom2d_TrimmedCurve,
                          Geom2dConvert.CurveToBSplineCurve_s, Geom2dConvert_ApproxCurve)


def _aligned(a: float, b: float, lo: float, hi: float) -> float:
    """The shift that moves domain [a, b] onto [lo, hi].

    Trimming a periodic kernel curve or surface normalizes its parameters into the first period
    (a circle trimmed to [-pi/2, pi/2] comes back on [3pi/2, 5pi/2]); shifting the knots back by
    whole periods restores the parameterization the pcurves and edges use.
    """
    if abs(a - lo) <= 1e-12 * max(1.0, abs(lo)) or abs((b - a) - (hi - lo)) > 1e-9 * max(1.0, hi - lo):
        return 0.0
    return lo - a


def align_curve(c: BSplineCurve, first: float, last: float) -> BSplineCurve:
    shift = _aligned(*c.domain, first, last)
    return c if shift == 0.0 else BSplineCurve(c.degree, c.knots + shift, c.poles, c.weights)


def align_surface(s: BSplineSurface, box) -> BSplineSurface:
    u0, u1, v0, v1 = s.domain
    du, dv = _aligned(u0, u1, box[0], box[1]), _aligned(v0, v1, box[2], box[3])
    if du == 0.0 and dv == 0.0:
        return s
    return BSplineSurface(s.udegree, s.vdegree, s.uknots + du, s.vknots + dv, s.poles, s.weights)


def surface_bspline(surf, bounds, tolerance: float) -> tuple[Geom_BSplineSurface, float]:
    """A surface as a B-spline in its own parameters over ``bounds``; (surface, error bound).

    B-splines are kept; other surfaces are converted exactly when the conversion keeps the
    parameterization (planes, extrusions, Bezier), else approximated over the face's domain so
    that the face's pcurves stay valid (cylinders, cones, spheres, tori, revolutions in angle,
    offsets).
    """
    if isinstance(surf, Geom_BSplineSurface):
        return _unroll_surface(surf, bounds), 0.0
    u0, u1, v0, v1 = _pad(surf, bounds)
    trimmed = Geom_RectangularTrimmedSurface(surf, u0, u1, v0, v1)
    rng = np.random.default_rng(7)  # fixed: the same input gives the same output
    probes = [(u0 + a * (u1 - u0), v0 + b * (v1 - v0)) for a, b in rng.random((24, 2))]
    try:
        exact = GeomConvert.SurfaceToBSplineSurface_s(trimmed)
        if _keeps_parameter(surf, exact, probes, 1e-3 * tolerance):
            return exact, 0.0
    except Exception:  # noqa: BLE001 - e.g. Convert_TorusToBSplineSurface on a full torus
        pass
    approx = GeomConvert_ApproxSurface(trimmed, tolerance, GeomAbs_C2, GeomAbs_C2, _FIT_DEGREE, _FIT_DEGREE,
                                       _FIT_SEGMENTS, 1)
    if not approx.HasResult():
        raise KernelError(f"cannot convert a {type(surf).__name__} to B-spline")
    return approx.Surface(), float(approx.MaxError())


def _pad(surf, bounds):
    """The face's parameter box, grown by 1e-7 of its size where the surface allows it."""
    u0, u1, v0, v1 = bounds
    su0, su1, sv0, sv1 = surf.Bounds()
    du, dv = 1e-7 * (u1 - u0), 1e-7 * (v1 - v0)
    if surf.IsUPeriodic():  # a trim wider than the period would wrap around: stay within it
        du = max(0.0, min(du, (surf.UPeriod() - (u1 - u0)) / 2))
        su0, su1 = -math.inf, math.inf
    if surf.IsVPeriodic():
        dv = max(0.0, min(dv, (surf.VPeriod() - (v1 - v0)) / 2))
        sv0, sv1 = -math.inf, math.inf
    return max(u0 - du, su0), min(u1 + du, su1), max(v0 - dv, sv0), min(v1 + dv, sv1)


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


def _kernel_knots(curve) -> np.ndarray:
    """The distinct knots of a kernel curve (2D or 3D) that is a B-spline, or a trimmed one; else none."""
    while isinstance(curve, (Geom_TrimmedCurve, Geom2d_TrimmedCurve)):
        curve = curve.BasisCurve()
    if isinstance(curve, (Geom_BSplineCurve, Geom2d_BSplineCurve)):
        return _arr1(curve.Knots())
    return np.zeros(0)


def sample_tracks(shape: TopoDS_Shape, k: int, per_span: int = PER_SPAN,
                  params: dict | None = None) -> dict[int, tuple[np.ndarray | None, list]]:
    """The input's own boundary geometry, sampled with the kernel at the parameters of
    ``gaps.track_params``: k equal steps plus a few inside every knot span of the edge's 3D curve
    and pcurves.

    Returns, per non-degenerate edge index (the order of ``indexed(shape, TopAbs_EDGE)``):
    (C(w) as (m, 3) or None, [(face index, S_f(pc_f(w)) as (m, 3)), ...]) with seams giving two
    tracks for their face. These arrays feed the pure-numpy gap measurement in
    ``watertight_cli.gaps``: the report measures the input itself, not a conversion of it.
    ``per_span`` 0 gives the equal steps only; ``params``, when given, receives each edge's
    parameters (so ``gaps.model_tracks`` can sample the arrays at the same ones).

    S_f is evaluated by the surface itself (``Geom_Surface::Value``), not through an adaptor: the
    adaptors evaluate B-splines from a cached power-basis form of each span, which at degree 19
    and above is off by up to 4e-10 (a rational 19 x 19 patch of ``filleted_freeform.step``
    converted; the surface's own evaluation and the project's arrays agree within 1e-13).
    """
    fmap = indexed(shape, TopAbs_FACE)
    emap = indexed(shape, TopAbs_EDGE)
    e2f = edge_face_map(shape)
    out = {}
    for ei in range(1, emap.Extent() + 1):
        e = TopoDS.Edge_s(emap.FindKey(ei))
        if BRep_Tool.Degenerated_s(e):
            continue
        a, b = BRep_Tool.Range_s(e)
        c3 = BRep_Tool.Curve_s(e, 0.0, 0.0)
        knots = [] if c3 is None else [_kernel_knots(c3)]
        uses = []
        for f in (_unique_faces(e2f.FindFromKey(e)) if e2f.Contains(e) else []):
            fi = fmap.FindIndex(f) - 1
            for use in ([e, TopoDS.Edge_s(e.Reversed())] if BRep_Tool.IsClosed_s(e, f) else [e]):
                pc = BRep_Tool.CurveOnSurface_s(use, f, 0.0, 0.0)
                if pc is None:
                    continue
                knots.append(_kernel_knots(pc))
                uses.append((fi, pc, f))
        ws = track_params(a, b, k, knots, per_span)
        if params is not None:
            params[ei - 1] = ws
        cpts = np.array([c3.Value(w).Coord() for w in ws]) if c3 is not None else None
        tracks = []
        for fi, pc, f in uses:
            loc = TopLoc_Location()
            srf = BRep_Tool.Surface_s(f, loc)
            tr = loc.Transformation()
            uvs = [pc.Value(w) for w in ws]
            tracks.append((fi, np.array([srf.Value(uv.X(), uv.Y()).Transformed(tr).Coord() for uv in uvs])))
        out[ei - 1] = (cpts, tracks)
    return out


def build_model(shape: TopoDS_Shape, read: ReadResult, diag: float, sewing: SewingInfo | None, path: str,
                tol: Tolerances) -> Model:
    """The array model of a prepared shape.

    Faces and edges keep the numbering of ``indexed(shape, ...)``, so ``sample_tracks(shape)``
    and the model agree on indices. Conversion tolerance: ``tol.convert_rel`` x diagonal.
    """
    fmap = indexed(shape, TopAbs_FACE)
    emap = indexed(shape, TopAbs_EDGE)
    vmap = indexed(shape, TopAbs_VERTEX)
    e2f = edge_face_map(shape)
    fit = tol.convert_rel * diag
    merge = tol.knot_rel * diag  # knots the splines do not break at go (``BSplineCurve.merged``)

    vertices = np.array([BRep_Tool.Pnt_s(TopoDS.Vertex_s(vmap.FindKey(i))).Coord()
                         for i in range(1, vmap.Extent() + 1)], dtype=float).reshape(-1, 3)

    faces = [_face(TopoDS.Face_s(fmap.FindKey(fi)), fi - 1, emap, fit, merge)
             for fi in range(1, fmap.Extent() + 1)]

    edges: list[Edge] = []
    for ei in range(1, emap.Extent() + 1):
        e = TopoDS.Edge_s(emap.FindKey(ei))
        degenerate = BRep_Tool.Degenerated_s(e)
        first, last = BRep_Tool.Range_s(e)
        curve, error = None, 0.0
        if not degenerate:
            c = BRep_Tool.Curve_s(e, 0.0, 0.0)  # the 3-argument form applies the edge's location
            if c is not None:
                bs, error = curve_3d(c, first, last, fit)
                curve = align_curve(curve_arrays(bs), first, last).merged(merge)
        inc = _unique_faces(e2f.FindFromKey(e)) if e2f.Contains(e) else []
        face_ids = tuple(sorted(fmap.FindIndex(f) - 1 for f in inc))
        seam = any(BRep_Tool.IsClosed_s(e, f) for f in inc)
        ends = (TopExp.FirstVertex_s(e), TopExp.LastVertex_s(e))
        vids = tuple(vmap.FindIndex(v) - 1 if not v.IsNull() else -1 for v in ends)
        edges.append(Edge(ei - 1, curve, first, last, BRep_Tool.Tolerance_s(e), vids, face_ids, seam,
                          degenerate, approximation=error))

    return Model(path=path, faces=faces, edges=edges, vertices=vertices, diagonal=diag,
                 solids=count(shape, TopAbs_SOLID), shells=count(shape, TopAbs_SHELL),
                 units=read.units, sewing=sewing)


def _coedge(e, face, emap, speed: float, fit: float, merge: float) -> tuple[Coedge, float]:
    first, last = BRep_Tool.Range_s(e, face)
    pc = BRep_Tool.CurveOnSurface_s(e, face, 0.0, 0.0)
    if pc is None:
        return Coedge(emap.FindIndex(e) - 1, e.Orientation() == TopAbs_REVERSED, None, first, last), 0.0
    # parameter-space tolerance from the 3D one through the surface's largest speed
    bs, err2d = curve_2d(pc, first, last, fit / speed)
    return (Coedge(edge=emap.FindIndex(e) - 1, reversed=e.Orientation() == TopAbs_REVERSED,
                   pcurve=align_curve(curve_arrays(bs), first, last).merged(merge / speed), first=first,
                   last=last), err2d * speed)


def _surface_speed(a: BSplineSurface) -> float:
    """An upper bound of |dS/du|, |dS/dv| from the control net (hodograph bound), at least 1."""
    p, q = a.udegree, a.vdegree
    du = np.diff(a.poles, axis=0) * p / np.maximum(
        (a.uknots[p + 1:p + a.poles.shape[0]] - a.uknots[1:a.poles.shape[0]])[:, None, None], 1e-300)
    dv = np.diff(a.poles, axis=1) * q / np.maximum(
        (a.vknots[q + 1:q + a.poles.shape[1]] - a.vknots[1:a.poles.shape[1]])[None, :, None], 1e-300)
    w = 1.0 if a.weights is None else float(a.weights.max() / a.weights.min()) ** 2
    return max(1.0, w * float(max(np.linalg.norm(du, axis=-1).max(initial=0),
                                  np.linalg.norm(dv, axis=-1).max(initial=0))))


def _face(face, index: int, emap, fit: float, merge: float) -> Face:
    stype = surface_type_name(face)
    loc = TopLoc_Location()
    surf = BRep_Tool.Surface_s(face, loc)
    while isinstance(surf, Geom_RectangularTrimmedSurface):
        surf = surf.BasisSurface()
    if not loc.IsIdentity():
        surf = surf.Transformed(loc.Transformation())
    bounds = BRepTools.UVBounds_s(face)
    bs, approx = surface_bspline(surf, bounds, fit)
    arrays = align_surface(surface_arrays(bs), _pad(surf, bounds)) if approx else surface_arrays(bs)
    arrays = arrays.merged(merge)

    speed = _surface_speed(arrays)
    loops = []
    errors = [approx]
    outer = BRepTools.OuterWire_s(face)
    wires = indexed(face, TopAbs_WIRE)
    for wi in range(1, wires.Extent() + 1):
        wire = TopoDS.Wire_s(wires.FindKey(wi))
        uses = []
        explorer = BRepTools_WireExplorer(wire, face)
        while explorer.More():
            uses.append(explorer.Current())  # oriented as used in this wire
            explorer.Next()
        if not uses:  # wires the explorer cannot order (rare): fall back to storage order
            exp = TopExp_Explorer(wire, TopAbs_EDGE)
            while exp.More():
                uses.append(TopoDS.Edge_s(exp.Current()))
                exp.Next()
        coedges = []
        for e in uses:
            ce, err = _coedge(e, face, emap, speed, fit, merge)
            coedges.append(ce)
            errors.append(err)
        loops.append(Loop(tuple(coedges), outer=not outer.IsNull() and wire.IsSame(outer)))
    loops.sort(key=lambda lp: not lp.outer)
    return Face(index=index, surface=arrays, surface_type=stype,
                reversed=face.Orientation() == TopAbs_REVERSED, loops=tuple(loops),
                uv_bounds=tuple(float(x) for x in bounds), approximation=max(errors))


__all__ = ["build_model", "surface_arrays", "surface_from_arrays", "curve_arrays", "curve_from_arrays",
           "diagonal", "free_edge_count", "needs_sewing", "prepare", "sample_tracks"]
