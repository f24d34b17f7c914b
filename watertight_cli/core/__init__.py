"""Numeric core: exact Bezier and rational-Bezier algebra on numpy arrays. Never imports OCP.

Modules (import them directly; this package imports nothing so that ``import watertight_cli.core`` stays
light):

- ``bernstein`` -- binomials, Bernstein basis values, exact univariate/bivariate products.
- ``bezier``    -- curve/surface evaluation, subdivision (de Casteljau, blossoming), degree elevation,
  homogeneous coordinates for rational objects.
- ``bspline``   -- knot insertion (NURBS Book A5.1) and Bezier extraction of B-spline curves/surfaces.
- ``compose``   -- exact composition S(phi(s, t)) with ruled, paper and general polynomial cell maps.
- ``approx``    -- least-squares Bezier fitting with exact end points (single and piecewise).
- ``reduce``    -- degree reduction of curves/patches with certified (convex hull) error bounds.
"""
