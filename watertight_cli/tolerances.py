"""The one tolerance object of the project, passed down explicitly.

Every default is relative to the model's bounding-box diagonal, so a part in millimetres and the
same part in metres behave alike. Each field documents why it has its value.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Tolerances:
    """Numerical tolerances, relative to the model diagonal unless the name ends in ``_abs``.

    Attributes
    ----------
    gap_samples:
        Equally spaced samples per edge for gap measurement. 33 parameters (ends included) find
        the peak of a degree-8 deviation to within a few percent; the independent checker uses 24.
        ``gaps.track_params`` adds 3 inside every knot span of the edge's curves, where equal
        steps miss a short stretch of mismatch near an end.
    approx_rel:
        Allowed geometric deviation when the exact degree would exceed ``max_degree``
        (``--tolerance``). 1e-6 of the diagonal is 1 micron on a 1 m part: below what
        manufacturing and meshing resolve, and ten times above OCCT's default confusion
        tolerance (1e-7 absolute in mm models), so approximations are never confused with exact
        data.
    convert_rel:
        Accuracy of the B-spline form of surfaces and curves that have no exact B-spline form in
        their own parameterization (angular parameters of cylinders, cones, spheres, tori,
        circles): 1e-10 of the diagonal, ten times below ``exact_rel`` so that stage 1 can still
        claim exactness at 1e-9.
    exact_rel:
        What counts as exact: 1e-9 of the diagonal (invariant I4, stage 1 deviation).
    knot_rel:
        Knots across which a curve or surface read from the input is one polynomial to within this
        (relative to the diagonal, bounding the change of its control points) are removed on
        reading. 1e-12 of the diagonal is rounding: lofts and Booleans give their surfaces and
        edges the union of their sections' knots, and every knot is a slab line or a plan cut.
    watertight_rel:
        Largest gap allowed between neighbours after conversion: 1e-12 of the diagonal
        (invariant I2: floating point only).
    sew_max_rel:
        Upper bound for the sewing tolerance of unconnected inputs: 2 % of the diagonal. Real
        IGES exports leave gaps up to ~1e-3 of the diagonal; anything wider than 2 % would join
        features that are meant to be separate.
    sliver_rel:
        Narrowest cell stage 1 makes, relative to the diagonal: slab lines closer than this (in
        3D, through the surface's speed) are merged. 1e-8 of the diagonal is 1e-6 mm on a 100 mm
        part, ten times OCCT's confusion tolerance (1e-7), so no patch side is shorter than what
        the kernel keeps as an edge; the coverage this gives up is a strip at most this wide.
    thin_rel:
        Slab lines closer than this (in 3D, all along the face) merge too, but only where every
        cell beside them keeps a rung that its neighbour across the line shares: the merged line
        then bends a little through the piece ends it carries, and nothing is left uncovered, so
        the merge costs no deviation. 5e-7 of the diagonal, half the default ``approx_rel``: a
        strip narrower than that is below what the tolerance resolves, and as a patch 4e-5 wide
        and 42 long (trj8's planar faces 40 and 49, where a neighbour's cuts land 4e-5 apart in u)
        it is a face that BRepMesh leaves partly untriangulated.
    slender_ratio:
        Longest an edge along a finished patch's long side may be for the patch's width (a ratio,
        not relative to the diagonal): the long sides of longer patches are split into shorter
        edges, the patch kept whole (``core.slender``, ``topology.split``). Stage 1 leaves strips
        thousands of times longer than wide where slab lines or knot lines run close together. A
        checker that samples every edge at a fixed count (the independent one takes 272) then
        finds a third face's boundary nearer than the neighbour's samples once the neighbour's
        edge is about 540 times longer than the strip is wide. 250 keeps a margin of two; 100
        (the default before 2026-12-06, when strips were still cut across into pieces) made 2-2.5
        times as many pieces for no better checker figures on the fixtures (unmatched boundary
        samples 16 at 100, 6 at 250, 10 at 400). Every edge is also kept no longer than this ratio
        times its distance to the nearest other edge, where that distance is above ``approx_rel``
        (``topology.clearance_points``): a third face's boundary beyond a thin neighbour.
    max_degree:
        Largest patch degree (``--max-degree``). 25 is OCCT's Bezier limit
        (``Geom_BezierSurface::MaxDegree``).
    strict:
        Turns on internal invariant checks (the test suite sets it).
    wrap_tips:
        Wraps the u-extrema of trimming curves in turned cells instead of putting a slab line
        through them (``--wrap-tips``, ``wrap``): no patch corner of zero angle there. On by
        default: at such a corner two sides of one patch part only as the square of the distance
        from it, and a check that pairs each boundary sample with the nearest boundary of another
        face (the independent checker's) finds the neighbour across the tangent line nearer than
        the partner across the curve (plate_with_holes: 16 samples over 1e-9 of the diagonal
        without the wraps, none with them). It costs patches (plate_with_holes 291 -> 403).
    """

    gap_samples: int = 33
    approx_rel: float = 1e-6
    convert_rel: float = 1e-10
    exact_rel: float = 1e-9
    knot_rel: float = 1e-12
    watertight_rel: float = 1e-12
    sew_max_rel: float = 2e-2
    sliver_rel: float = 1e-8
    thin_rel: float = 5e-7
    slender_ratio: float = 250.0
    max_degree: int = 25
    strict: bool = False
    wrap_tips: bool = True

    #: OCCT's hard limit on Bezier degree (Geom_BezierSurface::MaxDegree()).
    OCCT_MAX_DEGREE = 25

    def __post_init__(self):
        if not 1 <= self.max_degree <= self.OCCT_MAX_DEGREE:
            raise ValueError(f"max_degree must be in 1..{self.OCCT_MAX_DEGREE} (OCCT's Bezier limit)")
        if self.approx_rel <= 0:
            raise ValueError("tolerance must be positive")
        if self.slender_ratio <= 1:
            raise ValueError("slender_ratio must be above 1")
        if self.gap_samples < 3:
            raise ValueError("gap_samples must be at least 3")

    def with_(self, **kw) -> Tolerances:
        return replace(self, **kw)
