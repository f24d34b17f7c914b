"""Degree reduction of Bezier curves and patches with certified error bounds.

Method: constrained linear least squares on the control points (Eck 1993, "Degree reduction of Bezier
curves"; Farin ch. 5 on the elevation operator). With E the elevation matrix from the target degree back
to the original one, we look for Q minimizing || E Q - P || subject to end constraints, and report

    bound = max_i || (E Q - P)_i ||          (Euclidean norm per control point)

which bounds the true deviation max_t || Q(t) - P(t) || because E Q and P are two control nets of the
same degree and the Bernstein basis is a partition of unity (convex hull property). For homogeneous
(rational) nets the bound is on the homogeneous difference; divide by the smallest weight of the curve
for a (looser) Cartesian statement.
"""

from __future__ import annotations

import functools

import numpy as np

from .bezier import elevate_curve, elevation_matrix

__all__ = ["reduce_curve", "reduce_surface", "reduction_bound"]


@functools.lru_cache(maxsize=1024)
def _pinv(target: int, r: int) -> np.ndarray:
    """pinv of the elevation matrix from degree ``target`` by ``r`` (read-only, cached: the same few
    degree pairs come back for every patch, and the SVDs were half of ``reduce_surface``)."""
    out = np.linalg.pinv(elevation_matrix(target, r))
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=1024)
def _interior_pinv(target: int, r: int) -> np.ndarray:
    """pinv of the elevation matrix's inner columns (the boundary held), cached as ``_pinv``."""
    out = np.linalg.pinv(elevation_matrix(target, r)[:, 1:-1])
    out.flags.writeable = False
    return out


def reduction_bound(ctrl, new_ctrl) -> float:
    """max_i || elevate(new_ctrl)_i - ctrl_i ||: a certified upper bound of the curve/patch deviation.

    ctrl : (n+1, d) or (m+1, n+1, d); new_ctrl of lower or equal degree(s). Returns float.
    """
    ctrl = np.asarray(ctrl, dtype=float)
    new_ctrl = np.asarray(new_ctrl, dtype=float)
    if ctrl.ndim == 2:
        up = elevate_curve(new_ctrl, ctrl.shape[0] - new_ctrl.shape[0])
    else:
        eu = elevation_matrix(new_ctrl.shape[0] - 1, ctrl.shape[0] - new_ctrl.shape[0])
        ev = elevation_matrix(new_ctrl.shape[1] - 1, ctrl.shape[1] - new_ctrl.shape[1])
        up = np.einsum("ai,ijd,bj->abd", eu, new_ctrl, ev)
    return float(np.max(np.linalg.norm(up - ctrl, axis=-1)))


def reduce_curve(ctrl, target: int, fix_ends: int = 1) -> tuple[np.ndarray, float]:
    """Reduce a Bezier curve to degree ``target`` by constrained least squares.

    Parameters
    ----------
    ctrl : (n+1, d) float (polynomial, or homogeneous rational).
    target : int, 0 <= target. target >= n returns the curve elevated to ``target`` (exact, bound 0).
    fix_ends : int k >= 1: the first k and last k control points of elevate(new_ctrl) equal those of ctrl,
        i.e. position and derivatives up to order k-1 are kept at both ends (k = 1: end points exactly,
        new_ctrl[0] == ctrl[0] and new_ctrl[-1] == ctrl[-1] bit for bit). Needs 2k <= target + 1.

    Returns
    -------
    (new_ctrl : (target+1, d) float, bound : float), bound = max_i ||(E new_ctrl - ctrl)_i|| >= the true
    maximum deviation of the two curves.
    """
    ctrl = np.asarray(ctrl, dtype=float)
    if ctrl.ndim != 2:
        raise ValueError(f"reduce_curve: ctrl must be (n+1, d), got shape {ctrl.shape}")
    n = ctrl.shape[0] - 1
    target = int(target)
    k = int(fix_ends)
    if target < 0:
        raise ValueError(f"reduce_curve: target degree must be >= 0, got {target}")
    if target >= n:
        return elevate_curve(ctrl, target - n), 0.0
    if k < 1 or 2 * k > target + 1:
        raise ValueError(
            f"reduce_curve: fix_ends={k} needs 1 <= fix_ends and 2*fix_ends <= target+1 = {target + 1}"
        )
    e = elevation_matrix(target, n - target)  # (n+1, target+1)
    q = np.zeros((target + 1, ctrl.shape[1]))
    # Leading constraints (E Q)[i] = P[i], i < k: E[:k, :k] is lower triangular with E[0, 0] = 1.
    for i in range(k):
        q[i] = (ctrl[i] - e[i, :i] @ q[:i]) / e[i, i]
    # Trailing constraints (E Q)[n-i] = P[n-i]: E[n-k+1:, target-k+1:] is upper triangular, E[n, target] = 1.
    for i in range(k):
        row, col = n - i, target - i
        q[col] = (ctrl[row] - e[row, col + 1 :] @ q[col + 1 :]) / e[row, col]
    free = slice(k, target + 1 - k)
    if target + 1 - 2 * k > 0:
        rhs = ctrl - e[:, :k] @ q[:k] - e[:, target + 1 - k :] @ q[target + 1 - k :]
        sol, *_ = np.linalg.lstsq(e[:, free], rhs, rcond=None)
        q[free] = sol
    bound = float(np.max(np.linalg.norm(e @ q - ctrl, axis=-1)))
    return q, bound


def reduce_surface(
    ctrl,
    mt: int,
    nt: int,
    fix_boundary: bool = True,
    boundaries=None,
    boundary_tol: float | None = None,
) -> tuple[np.ndarray, float]:
    """Reduce a tensor-product Bezier patch to bidegree (mt, nt).

    Parameters
    ----------
    ctrl : (m+1, n+1, d) float (polynomial, or homogeneous rational).
    mt, nt : target degrees; a target above the current degree elevates that direction (exactly).
    fix_boundary : when True, the four boundary curves of the result are chosen first and held fixed:
        by default each is reduce_curve(boundary row of ctrl, target, fix_ends=1), so the corners are kept
        bit for bit and the same boundary row (same orientation) always reduces to the same curve. The
        interior is then the least-squares solution given the boundary. When False, all control points are
        free (unconstrained tensor least squares, Q = E_u^+ P E_v^+T).
    boundaries : optional (row_u0 (nt+1, d), row_u1 (nt+1, d), col_v0 (mt+1, d), col_v1 (mt+1, d)), the
        boundary curves to use verbatim (e.g. shared curves already reduced once for both neighbours);
        their corners must agree exactly. Implies fix_boundary.
    boundary_tol : optional; with fix_boundary, raise ValueError if a boundary curve cannot be reduced
        within this deviation (bound of its own reduction), i.e. when the boundary would have to move.

    Returns
    -------
    (new : (mt+1, nt+1, d) float, bound : float), bound = max_ij ||(E_u new E_v^T - ctrl)_ij||, a certified
    upper bound of the patch deviation (convex hull property).
    """
    ctrl = np.asarray(ctrl, dtype=float)
    if ctrl.ndim != 3:
        raise ValueError(f"reduce_surface: ctrl must be (m+1, n+1, d), got shape {ctrl.shape}")
    mt, nt = int(mt), int(nt)
    if mt < 1 or nt < 1:
        raise ValueError(f"reduce_surface: target bidegree must be >= (1, 1), got ({mt}, {nt})")
    m, n = ctrl.shape[0] - 1, ctrl.shape[1] - 1
    orig = ctrl
    # Elevate directions whose target exceeds the current degree (exact).
    if mt > m or nt > n:
        eu0 = elevation_matrix(m, max(mt - m, 0))
        ev0 = elevation_matrix(n, max(nt - n, 0))
        ctrl = np.einsum("ai,ijd,bj->abd", eu0, ctrl, ev0)
        m, n = ctrl.shape[0] - 1, ctrl.shape[1] - 1
    eu = elevation_matrix(mt, m - mt)  # (m+1, mt+1)
    ev = elevation_matrix(nt, n - nt)  # (n+1, nt+1)
    d = ctrl.shape[2]

    if boundaries is None and not fix_boundary:
        q = np.einsum("ia,ijd,jb->abd", _pinv(mt, m - mt).T, ctrl, _pinv(nt, n - nt).T)
        return q, reduction_bound(ctrl, q)

    q = np.zeros((mt + 1, nt + 1, d))
    if boundaries is not None:
        r0, r1, c0, c1 = (np.asarray(x, dtype=float) for x in boundaries)
        row_shape, col_shape = (nt + 1, d), (mt + 1, d)
        if (r0.shape, r1.shape, c0.shape, c1.shape) != (row_shape, row_shape, col_shape, col_shape):
            raise ValueError(
                f"reduce_surface: boundaries must be two rows {row_shape} and two columns {col_shape}"
            )
        corners_ok = (
            np.array_equal(r0[0], c0[0])
            and np.array_equal(r0[-1], c1[0])
            and np.array_equal(r1[0], c0[-1])
            and np.array_equal(r1[-1], c1[-1])
        )
        if not corners_ok:
            raise ValueError("reduce_surface: the given boundary curves do not share their corners exactly")
    else:
        reduced = []
        # From the original rows, so a boundary row always reduces to exactly reduce_curve(row, target).
        for curve, tgt in ((orig[0], nt), (orig[-1], nt), (orig[:, 0], mt), (orig[:, -1], mt)):
            c, b = reduce_curve(curve, tgt, fix_ends=1)
            if boundary_tol is not None and b > boundary_tol:
                raise ValueError(
                    f"reduce_surface: a boundary curve of degree {curve.shape[0] - 1} cannot be reduced to "
                    f"degree {tgt} within {boundary_tol} (bound {b:.3g})"
                )
            reduced.append(c)
        r0, r1, c0, c1 = reduced
    q[0], q[-1] = r0, r1
    q[:, 0], q[:, -1] = c0, c1
    if mt >= 2 and nt >= 2:
        # Interior: min || E_u^I X E_v^I^T - R ||_F with R the residual of the fixed boundary;
        # the solution is X = pinv(E_u^I) R pinv(E_v^I)^T (pinv of a Kronecker product).
        qb = q.copy()
        resid = ctrl - np.einsum("ai,ijd,bj->abd", eu, qb, ev)
        pu = _interior_pinv(mt, m - mt)  # (mt-1, m+1)
        pv = _interior_pinv(nt, n - nt)  # (nt-1, n+1)
        q[1:-1, 1:-1] = np.einsum("ai,ijd,bj->abd", pu, resid, pv)
    return q, reduction_bound(ctrl, q)
