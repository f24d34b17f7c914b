"""Build OCCT faces from Bezier patches, and measure input faces for the verify step.

A patch is an untrimmed ``Geom_BezierSurface`` bounded by its natural [0, 1]^2 domain. Stage 1
output has no shared edges yet (stage 2 makes them), so the faces go into one open shell; a patch of
a REVERSED input face becomes a REVERSED face, so its normal points the same way as the input's.
"""

from __future__ import annotations

import numpy as np
from OCP.BRep import BRep_Builder
from OCP.BRepGProp import BRepGProp
from OCP.Geom import Geom_BezierSurface
from OCP.Geom2d import Geom2d_Line
from OCP.gp import gp_Dir2d, gp_Pnt, gp_Pnt2d
from OCP.GProp import GProp_GProps
from OCP.TColgp import TColgp_Array2OfPnt
from OCP.TColStd import TColStd_Array2OfReal
from OCP.TopAbs import TopAbs_FACE, TopAbs_FORWARD, TopAbs_REVERSED
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS, TopoDS_Edge, TopoDS_Face, TopoDS_Shell, TopoDS_Vertex, TopoDS_Wire

from ..errors import KernelError
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
