"""Build OCCT faces from Bezier patches, and measure input faces for the verify step.

A patch is an untrimmed ``Geom_BezierSurface`` bounded by its natural [0, 1]^2 domain. Stage 1
output has no shared edges yet (stage 2 makes them), so the faces go into one compound; a patch of
a REVERSED input face becomes a REVERSED face, so its normal points the same way as the input's.
"""

from __future__ import annotations

import numpy as np
from OCP.BRep import BRep_Builder
from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
from OCP.BRepGProp import BRepGProp
from OCP.Geom import Geom_BezierSurface
from OCP.gp import gp_Pnt
from OCP.GProp import GProp_GProps
from OCP.TColgp import TColgp_Array2OfPnt
from OCP.TColStd import TColStd_Array2OfReal
from OCP.TopAbs import TopAbs_FACE
from OCP.TopoDS import TopoDS, TopoDS_Compound, TopoDS_Face

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
    """An untrimmed face on the patch's whole [0, 1]^2 domain."""
    maker = BRepBuilderAPI_MakeFace(bezier_surface(ctrl, rational), FACE_TOLERANCE)
    if not maker.IsDone():
        raise KernelError("the kernel could not make a face from a Bezier patch")
    face = maker.Face()
    return TopoDS.Face_s(face.Reversed()) if reversed_ else face


def compound(faces) -> TopoDS_Compound:
    comp = TopoDS_Compound()
    builder = BRep_Builder()
    builder.MakeCompound(comp)
    for f in faces:
        builder.Add(comp, f)
    return comp


def face_area(face) -> float:
    props = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, props, 1e-10)  # adaptive: the default rule is off by 1e-4 on some planes
    return float(props.Mass())


def input_face_areas(shape) -> np.ndarray:
    """Area of every face of a prepared shape, in the model's face numbering."""
    fmap = indexed(shape, TopAbs_FACE)
    return np.array([face_area(TopoDS.Face_s(fmap.FindKey(i))) for i in range(1, fmap.Extent() + 1)])
