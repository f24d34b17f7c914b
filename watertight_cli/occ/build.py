"""Build OCCT faces from Bezier patches, and measure input faces for the verify step.

A patch is an untrimmed ``Geom_BezierSurface`` bounded by its natural [0, 1]^2 domain. Stage 1
output has no shared edges yet (stage 2 makes them), so the faces go into one open shell; a patch of
a REVERSED input face becomes a REVERSED face, so its normal points the same way as the input's.
"""

from __future__ import annotations

import numpy as np
from OCP.BRep import BRep_Builder
from OCP.BRepGProp import BRepGProp
from OCP.Geom import Geom_BezierCurve, Geom_BezierSurface
from OCP.Geom2d import Geom2d_BSplineCurve, Geom2d_Line
from OCP.gp import gp_Dir2d, gp_Pnt, gp_Pnt2d
from OCP.GProp import GProp_GProps
from OCP.TColgp import TColgp_Array1OfPnt, TColgp_Array1OfPnt2d, TColgp_Array2OfPnt
from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal, TColStd_Array2OfReal
from OCP.TopAbs import TopAbs_FACE, TopAbs_FORWARD, TopAbs_REVERSED
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS, TopoDS_Edge, TopoDS_Face, TopoDS_Shell, TopoDS_Vertex, TopoDS_Wire

from ..core.bezier import curve_segment
from ..errors import KernelError
from ..topology import forward, side_row, wire_order
from .extract import indexed

#: tolerance given to the built faces' edges and vertices (model units): OCCT's confusion value
FACE_TOLERANCE = 1e-7


def bezier_surface(ctrl: np.ndarray, rational: bool) -> Geom_BezierSurface:
    """A ``Geom_BezierSurface`` from a (m+1, n+1, 3) net, or (m+1, n+1, 4) homogeneous when rational."""
    m, n = ctrl.shape[0] - 1, ctrl.shape[1] - 1
    poles = TColgp_Array2OfPnt(1, m + 1, 1, n + 1)
    if rational:
        w = ctrl[..., 3]
        if not np.all(w > 0):
            raise KernelError("a rational patch has a weight that is not positive")
        xyz = ctrl[..., :3] / w[..., None]
    else:
        xyz = ctrl
    for i in range(m + 1):
        for j in range(n + 1):
            poles.SetValue(i + 1, j + 1, gp_Pnt(*map(float, xyz[i, j])))
    if not rational:
        return Geom_BezierSurface(poles)
    weights = TColStd_Array2OfReal(1, m + 1, 1, n + 1)
    for i in range(m + 1):
        for j in range(n + 1):
            weights.SetValue(i + 1, j + 1, float(w[i, j]))
    return Geom_BezierSurface(poles, weights)


def patch_face(ctrl: np.ndarray, rational: bool, reversed_: bool) -> TopoDS_Face:
    """An untrimmed face on the patch's whole [0, 1]^2 domain, built edge by edge.

    The four sides are the surface's iso-curves (exact Bezier curves, same parameter as their
    straight pcurves); a side whose control points all coincide (a pole, or the collapsed rung of
    a triangular cell) becomes a degenerated edge on one vertex. ``BRepBuilderAPI_MakeFace`` is
    not used: it drops collapsed sides, leaving three-edge faces that read as trimmed.
    """
    surf = bezier_surface(ctrl, rational)
    xyz = ctrl[..., :3] / ctrl[..., 3:4] if rational else ctrl
    scale = float(np.ptp(xyz.reshape(-1, 3), axis=0).max()) or 1.0
    rows = {  # side -> its control points
        "bottom": xyz[:, 0], "right": xyz[-1, :], "top": xyz[:, -1], "left": xyz[0, :]}
    collapsed = {k: bool(np.max(np.linalg.norm(r - r[0], axis=1)) <= 1e-12 * scale) for k, r in rows.items()}

    B = BRep_Builder()
    face = TopoDS_Face()
    B.MakeFace(face, surf, TopLoc_Location(), FACE_TOLERANCE)
    corner = {}
    for key, (u, v) in {"00": (0, 0), "10": (1, 0), "11": (1, 1), "01": (0, 1)}.items():
        vx = TopoDS_Vertex()
        B.MakeVertex(vx, surf.Value(float(u), float(v)), FACE_TOLERANCE)
        corner[key] = vx
    # collapsed sides share one vertex between their two corners
    for side, (a, b) in {"bottom": ("00", "10"), "right": ("10", "11"), "top": ("01", "11"),
                         "left": ("00", "01")}.items():
        if collapsed[side]:
            corner[b] = corner[a]
    sides = [  # (name, 3D iso-curve, pcurve origin, direction, first vertex, last vertex, wire sense)
        ("bottom", surf.VIso(0.0), (0.0, 0.0), (1.0, 0.0), "00", "10", TopAbs_FORWARD),
        ("right", surf.UIso(1.0), (1.0, 0.0), (0.0, 1.0), "10", "11", TopAbs_FORWARD),
        ("top", surf.VIso(1.0), (0.0, 1.0), (1.0, 0.0), "01", "11", TopAbs_REVERSED),
        ("left", surf.UIso(0.0), (0.0, 0.0), (0.0, 1.0), "00", "01", TopAbs_REVERSED),
    ]
    wire = TopoDS_Wire()
    B.MakeWire(wire)
    for name, curve, origin, direction, va, vb, sense in sides:
        edge = TopoDS_Edge()
        B.MakeEdge(edge)
        if collapsed[name]:
            B.Degenerated(edge, True)
        else:
            B.UpdateEdge(edge, curve, FACE_TOLERANCE)
        B.UpdateEdge(edge, Geom2d_Line(gp_Pnt2d(*origin), gp_Dir2d(*direction)), face, FACE_TOLERANCE)
        B.Range(edge, 0.0, 1.0)
        B.Add(edge, corner[va].Oriented(TopAbs_FORWARD))
        B.Add(edge, corner[vb].Oriented(TopAbs_REVERSED))
        B.SameParameter(edge, True)
        B.SameRange(edge, True)
        B.Add(wire, edge.Oriented(sense))
    B.Add(face, wire)
    B.NaturalRestriction(face, True)
    return TopoDS.Face_s(face.Reversed()) if reversed_ else face


def open_shell(faces) -> TopoDS_Shell:
    """One shell holding all faces (stage 1 faces share no edges, so it is an open shell).

    A compound of bare faces would be written to STEP as an assembly with one product per face,
    whose names carry a per-process counter (different bytes on a second conversion, against I6).
    """
    shell = TopoDS_Shell()
    builder = BRep_Builder()
    builder.MakeShell(shell)
    for f in faces:
        builder.Add(shell, f)
    shell.Closed(False)
    return shell


def face_area(face) -> tuple[float, float]:
    """The kernel's area of a (trimmed) face by its two integrators: (adaptive, fixed Gauss rule).

    They disagree by up to 2e-4 of the area on some faces (surfaces of linear extrusion, faces
    with a pole), and neither is always the better one, so both are returned and the verify step
    treats the interval between them as the reference.
    """
    props = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, props, 1e-10)
    adaptive = float(props.Mass())
    props = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, props)
    return adaptive, float(props.Mass())


def input_face_areas(shape) -> np.ndarray:
    """(faces, 2): the kernel's two areas of every face of a prepared shape (see ``face_area``), in
    the model's face numbering."""
    fmap = indexed(shape, TopAbs_FACE)
    return np.array([face_area(TopoDS.Face_s(fmap.FindKey(i))) for i in range(1, fmap.Extent() + 1)])


# ------------------------------------------------------------------ faces joined by shared edges

_SIDE_UV = {  # side -> (uv at side parameter 0, d uv / d s)
    "bottom": ((0.0, 0.0), (1.0, 0.0)),
    "right": ((1.0, 0.0), (0.0, 1.0)),
    "top": ((0.0, 1.0), (1.0, 0.0)),
    "left": ((0.0, 0.0), (0.0, 1.0)),
}


def _side_uv(side: str, s: float) -> gp_Pnt2d:
    (u0, v0), (du, dv) = _SIDE_UV[side]
    return gp_Pnt2d(u0 + s * du, v0 + s * dv)


def _pcurve(side: str, s0: float, s1: float, w: float, smap: np.ndarray | None = None):
    """The straight pcurve of a side piece: edge parameter a in [0, 1] to the side's s from s0 to
    s1 (affine, or the rational linear map with end weights 1 and w, or the spline ``smap``,
    (knots, coefficients)); its poles all lie on the side."""

    if smap is not None:
        knots_full, coef = smap
        poles = TColgp_Array1OfPnt2d(1, len(coef))
        for k, c in enumerate(coef):
            poles.SetValue(k + 1, _side_uv(side, float(c)))
        inner = np.unique(knots_full)
        knots = TColStd_Array1OfReal(1, len(inner))
        mults = TColStd_Array1OfInteger(1, len(inner))
        for k, x in enumerate(inner):
            knots.SetValue(k + 1, float(x))
        degree = len(knots_full) - len(coef) - 1
        for k in range(len(inner)):
            mults.SetValue(k + 1, degree + 1 if k in (0, len(inner) - 1) else 1)
        return Geom2d_BSplineCurve(poles, knots, mults, degree)
    poles = TColgp_Array1OfPnt2d(1, 2)
    poles.SetValue(1, _side_uv(side, s0))
    poles.SetValue(2, _side_uv(side, s1))
    knots = TColStd_Array1OfReal(1, 2)
    knots.SetValue(1, 0.0)
    knots.SetValue(2, 1.0)
    mults = TColStd_Array1OfInteger(1, 2)
    mults.SetValue(1, 2)
    mults.SetValue(2, 2)
    if w == 1.0:
        return Geom2d_BSplineCurve(poles, knots, mults, 1)
    weights = TColStd_Array1OfReal(1, 2)
    weights.SetValue(1, 1.0)
    weights.SetValue(2, float(w))
    return Geom2d_BSplineCurve(poles, weights, knots, mults, 1)


def _segment_curve(row: np.ndarray, t0: float, t1: float, rational: bool):
    """The piece [t0, t1] of a side's Bezier curve (homogeneous row) as a Bezier curve on [0, 1].
    An edge on its curve's whole range: a STEP reader finds the edge's parameters by projecting
    its vertices, which is exact only at the curve's ends (a sub-range came back 1e-8 off)."""

    seg = curve_segment(row, t0, t1) if (t0, t1) != (0.0, 1.0) else row
    poles = TColgp_Array1OfPnt(1, len(seg))
    for i, h in enumerate(seg):
        poles.SetValue(i + 1, gp_Pnt(*map(float, h[:3] / h[3])))
    if not rational:
        return Geom_BezierCurve(poles)
    weights = TColStd_Array1OfReal(1, len(seg))
    for i, h in enumerate(seg):
        weights.SetValue(i + 1, float(h[3]))
    return Geom_BezierCurve(poles, weights)


def joined_faces(nets: list[tuple[np.ndarray, bool, bool]], topo, tick=None) -> list[TopoDS_Face]:
    """Faces of the patches ``(ctrl, rational, reversed)`` bounded by the shared edges of ``topo``
    (``topology.connect`` on the same patches): one edge per shared boundary piece, one vertex per
    corner, straight pcurves on the sides of [0, 1]^2, same-parameter by construction. An edge's
    tolerance covers the deviation its members were measured with."""
    B = BRep_Builder()
    surfaces = [bezier_surface(ctrl, rational) for ctrl, rational, _ in nets]
    faces = []
    for surf in surfaces:
        f = TopoDS_Face()
        B.MakeFace(f, surf, TopLoc_Location(), FACE_TOLERANCE)
        faces.append(f)
    edge_tol = [max(FACE_TOLERANCE, 2.0 * max(m.deviation for m in e.members)) for e in topo.edges]
    vtol = np.maximum(FACE_TOLERANCE, 2.0 * topo.vertex_tolerance)
    for e, tol in zip(topo.edges, edge_tol, strict=True):
        vtol[e.va] = max(vtol[e.va], tol)
        vtol[e.vb] = max(vtol[e.vb], tol)
    vertices: dict[int, TopoDS_Vertex] = {}

    def vertex(i: int) -> TopoDS_Vertex:
        if i not in vertices:
            vx = TopoDS_Vertex()
            B.MakeVertex(vx, gp_Pnt(*map(float, topo.vertices[i])), float(vtol[i]))
            vertices[i] = vx
        return vertices[i]

    built: list[TopoDS_Edge] = []
    for e, tol in zip(topo.edges, edge_tol, strict=True):
        edge = TopoDS_Edge()
        B.MakeEdge(edge)
        if e.degenerate:
            m = e.owner
            B.Degenerated(edge, True)
            B.UpdateEdge(edge, _pcurve(m.side, 0.0, 1.0, 1.0), faces[m.patch], tol)
        else:
            o = e.owner
            ctrl, rational, _ = nets[o.patch]
            B.UpdateEdge(edge, _segment_curve(side_row(ctrl, rational, o.side), e.t0, e.t1, rational), tol)
            per_patch: dict[int, list] = {}
            for m in e.members:
                per_patch.setdefault(m.patch, []).append(m)
            for p, ms in per_patch.items():
                curves = [(_pcurve(m.side, m.s0, m.s1, m.w, m.smap), forward(m)) for m in ms]
                if len(curves) == 1:
                    B.UpdateEdge(edge, curves[0][0], faces[p], tol)
                else:  # a seam of one patch: the first pcurve is for the FORWARD use
                    curves.sort(key=lambda c: not c[1])
                    B.UpdateEdge(edge, curves[0][0], curves[1][0], faces[p], tol)
        B.Range(edge, 0.0, 1.0)
        B.Add(edge, vertex(e.va).Oriented(TopAbs_FORWARD))
        B.Add(edge, vertex(e.vb).Oriented(TopAbs_REVERSED))
        B.SameParameter(edge, True)
        B.SameRange(edge, True)
        built.append(edge)

    out = []
    for i, (wire_map, (_, _, reversed_)) in enumerate(zip(topo.wires, nets, strict=True)):
        wire = TopoDS_Wire()
        B.MakeWire(wire)
        for e_id, k in wire_order(wire_map):
            m = topo.edges[e_id].members[k]
            B.Add(wire, built[e_id].Oriented(TopAbs_FORWARD if forward(m) else TopAbs_REVERSED))
        wire.Closed(True)
        B.Add(faces[i], wire)
        B.NaturalRestriction(faces[i], True)
        out.append(TopoDS.Face_s(faces[i].Reversed()) if reversed_ else faces[i])
        if tick is not None:
            tick(1)
    return out
