"""The model as plain arrays: surfaces, pcurves, 3D curves, loops, edges. No OCP here.

``watertight_cli.occ.extract`` fills these from an OCCT shape; everything downstream (gap
measurement, the edge plan, cells, composition) reads only these arrays.

Conventions
-----------
- B-splines carry their *flat* knot vector (knots repeated by multiplicity), as in the NURBS Book.
  A curve of degree p with n poles has n + p + 1 knots. Periodic kernel objects are unperiodized
  before they get here, so every knot vector is an ordinary (usually clamped) one.
- Rational objects have ``weights``; ``homogeneous()`` returns premultiplied poles with the weight
  as last coordinate, which is what the Bezier core works on.
- Indices: faces, edges and vertices are numbered from 0 in the order of OCCT's indexed maps.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import BSpline, NdBSpline


def _cartesian(h: np.ndarray, rational: bool) -> np.ndarray:
    return h[:, :-1] / h[:, -1:] if rational else h


def _merged(knots: np.ndarray, degree: int, poles: np.ndarray, weights: np.ndarray | None, tol: float):
    """(knots, poles, weights) without the knots across which the spline is one polynomial (see
    ``core.bspline.merge_removable_spans``), or None. Weights are compared on the scale of the
    coordinates, so ``tol`` bounds the change of the homogeneous form in model units."""
    from .core.bspline import merge_removable_spans

    H = _homogeneous(poles, weights)
    scale = 1.0
    if weights is not None:
        scale = max(float(np.abs(poles).max(initial=0.0)), 1.0)
        H = H.copy()
        H[..., -1] *= scale
    out = merge_removable_spans(knots, degree, H, tol)
    if out is None:
        return None
    kn, Hm = out
    if weights is None:
        return kn, Hm, None
    w = Hm[..., -1] / scale
    return kn, Hm[..., :-1] / w[..., None], w


def _homogeneous(poles: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    if weights is None:
        return poles
    return np.concatenate([poles * weights[..., None], weights[..., None]], axis=-1)


@dataclass(frozen=True)
class BSplineCurve:
    """A (rational) B-spline curve in any dimension.

    degree : int
    knots : (n + degree + 1,) float, flat
    poles : (n, d) float
    weights : (n,) float or None (polynomial)
    """

    degree: int
    knots: np.ndarray
    poles: np.ndarray
    weights: np.ndarray | None = None

    @property
    def rational(self) -> bool:
        return self.weights is not None

    @property
    def dim(self) -> int:
        return self.poles.shape[1]

    @property
    def domain(self) -> tuple[float, float]:
        return float(self.knots[self.degree]), float(self.knots[-self.degree - 1])

    def homogeneous(self) -> np.ndarray:
        """(n, d+1) premultiplied poles and weights, or (n, d) poles when polynomial."""
        return _homogeneous(self.poles, self.weights)

    def merged(self, tol: float) -> BSplineCurve:
        """The same curve without knots it does not break at (within ``tol``); ``self`` if none."""
        out = _merged(self.knots, self.degree, self.poles, self.weights, tol)
        return self if out is None else BSplineCurve(self.degree, *out)

    def evaluate(self, t: np.ndarray) -> np.ndarray:
        """Points at parameters ``t`` (k,) -> (k, d).

        Outside the domain the end spans' polynomials are extended, as OCCT does: real files
        have pcurves that run slightly past their surface's knot range.
        """
        t = np.asarray(t, dtype=float)
        # construct_fast: the checks of BSpline() cost more than the evaluation of a short curve
        h = BSpline.construct_fast(np.ascontiguousarray(self.knots, dtype=float),
                                   np.ascontiguousarray(self.homogeneous(), dtype=float), self.degree,
                                   extrapolate=True)(t)
        return _cartesian(h, self.rational)


@dataclass(frozen=True)
class BSplineSurface:
    """A (rational) tensor-product B-spline surface in 3D.

    udegree, vdegree : int
    uknots : (nu + udegree + 1,) float, flat; vknots likewise
    poles : (nu, nv, 3) float, first axis along u
    weights : (nu, nv) float or None
    """

    udegree: int
    vdegree: int
    uknots: np.ndarray
    vknots: np.ndarray
    poles: np.ndarray
    weights: np.ndarray | None = None

    @property
    def rational(self) -> bool:
        return self.weights is not None

    @property
    def domain(self) -> tuple[float, float, float, float]:
        p, q = self.udegree, self.vdegree
        return (float(self.uknots[p]), float(self.uknots[-p - 1]),
                float(self.vknots[q]), float(self.vknots[-q - 1]))

    @property
    def is_bezier(self) -> bool:
        """One span each way: a Bezier patch."""
        return self.poles.shape[0] == self.udegree + 1 and self.poles.shape[1] == self.vdegree + 1

    def homogeneous(self) -> np.ndarray:
        return _homogeneous(self.poles, self.weights)

    def merged(self, tol: float) -> BSplineSurface:
        """The same surface without u- or v-knots it does not break at (within ``tol``); ``self`` if
        none: a lofted or Boolean-made surface often carries the union of its sections' knots."""
        s = self
        out = _merged(s.uknots, s.udegree, s.poles, s.weights, tol)
        if out is not None:
            s = BSplineSurface(s.udegree, s.vdegree, out[0], s.vknots, out[1], out[2])
        w = None if s.weights is None else s.weights.T
        out = _merged(s.vknots, s.vdegree, np.swapaxes(s.poles, 0, 1), w, tol)
        if out is not None:
            poles = np.ascontiguousarray(np.swapaxes(out[1], 0, 1))
            weights = None if out[2] is None else np.ascontiguousarray(out[2].T)
            s = BSplineSurface(s.udegree, s.vdegree, s.uknots, out[0], poles, weights)
        return s

    def evaluate(self, uv: np.ndarray) -> np.ndarray:
        """Points at parameter pairs ``uv`` (k, 2) -> (k, 3); end spans extend past the domain."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        spl = NdBSpline((self.uknots, self.vknots), self.homogeneous(), (self.udegree, self.vdegree),
                        extrapolate=True)
        return _cartesian(spl(uv), self.rational)


@dataclass(frozen=True)
class Coedge:
    """One use of an edge by a face: the edge, its sense in the loop and its pcurve.

    edge : index into ``Model.edges``
    reversed : the coedge runs from the edge's last parameter to its first
    pcurve : 2D curve in the face's (u, v) domain, parameterized like the edge's 3D curve
    first, last : parameter range of the pcurve (equal to the edge's range when same-parameter)
    """

    edge: int
    reversed: bool
    pcurve: BSplineCurve | None
    first: float
    last: float


@dataclass(frozen=True)
class Loop:
    """A closed chain of coedges. ``outer`` marks the outer loop of a face."""

    coedges: tuple[Coedge, ...]
    outer: bool


@dataclass(frozen=True)
class Face:
    """A trimmed face: surface (as converted to B-spline), orientation and trimming loops.

    surface_type : the kernel type before conversion, e.g. "Plane", "BSpline", "Cylindrical"
    reversed : the face's normal is opposite to the surface normal
    approximation : error bound of the B-spline form of the face (surface and pcurves), 0.0
        when exact; surfaces with angular parameters (cylinder, cone, sphere, torus) and conic
        pcurves are approximated in their own parameterization
    uv_bounds : (u0, u1, v0, v1) of the trimmed region
    """

    index: int
    surface: BSplineSurface
    surface_type: str
    reversed: bool
    loops: tuple[Loop, ...]
    uv_bounds: tuple[float, float, float, float]
    approximation: float = 0.0
    turned: bool = False  # u and v swapped by stage 1 (``untrim.transpose_face``)


@dataclass(frozen=True)
class Edge:
    """An edge of the model.

    curve : its 3D curve as a B-spline, None for degenerated edges (poles)
    first, last : parameter range
    tolerance : the kernel's edge tolerance
    vertices : (start, end) indices into ``Model.vertices``
    faces : indices of the faces that use it (a seam lists its face once)
    seam : closed on one of its faces (used twice by that face)
    degenerate : collapsed to a point (a pole)
    """

    index: int
    curve: BSplineCurve | None
    first: float
    last: float
    tolerance: float
    vertices: tuple[int, int]
    faces: tuple[int, ...]
    seam: bool
    degenerate: bool
    approximation: float = 0.0  # error bound of the B-spline form of the 3D curve (conics)

    @property
    def uses(self) -> int:
        """How many face sides use the edge: 1 free, 2 manifold, more non-manifold."""
        return len(self.faces) + (1 if self.seam else 0)


@dataclass
class SewingInfo:
    """What sewing did to an unconnected input."""

    tolerance: float
    free_edges_before: int
    free_edges_after: int
    edges_joined: int
    max_join_distance: float
    input_max_gap: float = 0.0  # largest C vs S(pc) gap of the faces as read, before sewing


@dataclass
class Model:
    """A whole model as arrays.

    vertices : (k, 3) float
    diagonal : bounding-box diagonal of the input shape
    """

    path: str
    faces: list[Face]
    edges: list[Edge]
    vertices: np.ndarray
    diagonal: float
    solids: int
    shells: int
    units: str = "mm"
    sewing: SewingInfo | None = None
    notes: list[str] = field(default_factory=list)

    def surface_types(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for f in self.faces:
            out[f.surface_type] = out.get(f.surface_type, 0) + 1
        return dict(sorted(out.items(), key=lambda kv: (-kv[1], kv[0])))
