"""Same-parameter repair of pcurves: make S(pc(t)) run with the edge's curve C(t).

Stage 1 cuts every edge at one list of edge parameters (the edge plan) and reads the cut on each
face as pc_f(t); stage 2 puts C(t) into the face's side at the same parameters. Both rely on
S_f(pc_f(t)) being near C(t) for every t, not only as a point set. Real files break this near edge
ends: in ``gmsh__wing_fuselage.step`` one pcurve runs at another speed than its edge over the first
1 % of the edge, so S(pc(t)) is 0.22 from C(t) while the two curves are only 0.014 apart as sets.
Uniform samples (the kernel's same-parameter check, the gap report) step over such a stretch.

This module finds such coedges with samples that follow the knots of both curves and gives them a
new pcurve with the same trace in the face's domain, re-timed so that S(pc(t)) is near C(t):

    phi(t) = argmin_s |S(pc(s)) - C(t)|  (made monotone),   pc_new = pc o phi_lin  (exact)

where phi_lin is phi interpolated linearly between nodes: the edge curve's knots, and each pcurve
knot at phi^-1 (so every piece lies in one pcurve span). A knot that re-timing moves by less than
half the tolerance (in 3D) stays where it was, or moves onto a knot of C, so both faces of an
edge keep cutting it at the same parameters. Composing a Bezier piece with a linear map is exact:
the trim does not move at all and stage 1 stays exact. Between nodes S(pc_new(t)) can still run
off C(t) (``Retimed.after``); stage 2 moves the boundary by that much. Coedges whose mismatch is
not mainly one of timing (the trace itself is about as far from C as S(pc(t)) is) keep their
pcurve: re-timing would not help them.
Pure numpy/scipy on the array model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .core.bspline import split_curve_at
from .gaps import track_params
from .model import BSplineCurve, Coedge, Face, Loop, Model
from .tolerances import Tolerances

#: Samples in each knot span of the edge curve and of the pcurve, and uniform samples per coedge.
PER_SPAN, UNIFORM = 8, 128
#: A coedge is re-timed when S(pc(t)) stands farther from C(t) than this factor times the distance
#: of the trace from C (so the mismatch is mostly timing, not a gap).
TIMING_FACTOR = 2.0


@dataclass(frozen=True)
class Retimed:
    """One re-timed coedge: where, how far S(pc(t)) was from C(t) before and after, how far C is
    from the trace (the gap that re-timing cannot close) and the number of inner nodes of phi."""

    face: int
    edge: int
    before: float
    after: float
    trace_gap: float
    nodes: int


def sample_params(a: float, b: float, knot_vectors: list[np.ndarray]) -> np.ndarray:
    """Samples of [a, b] that crowd where the knots of the edge curve and the pcurve crowd."""
    return track_params(a, b, UNIFORM, knot_vectors, PER_SPAN)


def _phi(t: np.ndarray, c: np.ndarray, trace, s_grid: np.ndarray | None = None) -> np.ndarray:
    """Parameters s of the trace points nearest to the points c (taken at parameters t).

    trace(s) -> points. Nearest point of the trace at the parameters ``s_grid`` (sorted; default
    t) by a k-d tree, then the bracket around it is narrowed by 9-point searches (a factor 4 per
    round) and two Newton steps finish. Not yet monotone: see ``_monotone``."""
    if s_grid is None:
        s_grid = t
    pts = trace(s_grid)
    _, k = cKDTree(pts).query(c)
    lo = s_grid[np.maximum(k - 1, 0)]
    hi = s_grid[np.minimum(k + 1, len(s_grid) - 1)]
    frac = np.linspace(0.0, 1.0, 9)
    mid = s_grid[k]
    for _ in range(6):
        cand = lo[:, None] + (hi - lo)[:, None] * frac[None, :]
        d = np.linalg.norm(trace(cand.ravel()).reshape(len(t), 9, -1) - c[:, None, :], axis=2)
        j = np.argmin(d, axis=1)
        step = (hi - lo) / 8
        mid = cand[np.arange(len(t)), j]
        lo, hi = np.maximum(mid - step, lo), np.minimum(mid + step, hi)
    s = mid.copy()
    h = 1e-6 * (t[-1] - t[0])
    for _ in range(2):  # Newton steps on (trace(s) - c) . trace'(s) = 0, central differences
        d = trace(np.concatenate([s - h, s, s + h])).reshape(3, len(s), -1)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            tan = (d[2] - d[0]) / (2 * h)
            step = np.einsum("ij,ij->i", d[1] - c, tan) / np.maximum(np.einsum("ij,ij->i", tan, tan), 1e-300)
        s = np.clip(np.where(np.isfinite(step), s - step, s), lo, hi)
    return s


def _monotone(t: np.ndarray, s: np.ndarray) -> np.ndarray:
    """s with its ends pinned to t's (the vertices stay) and made non-decreasing."""
    s = s.copy()
    s[0], s[-1] = t[0], t[-1]
    return np.maximum.accumulate(s)


def retime(model: Model, tol: Tolerances) -> list[Retimed]:
    """Re-time the pcurves of ``model`` that are not same-parameter with their edge (in place:
    faces are replaced by copies with new pcurves). Returns one entry per re-timed coedge."""
    diag = model.diagonal
    # stage 2 may move a boundary by half the tolerance (the other half is stage 1's): a timing
    # mismatch within that is left as it is
    floor = 0.5 * tol.approx_rel * diag
    done: list[Retimed] = []
    for fi, face in enumerate(model.faces):
        surf = face.surface
        todo = _mismatched(model, face, floor)
        if not todo:
            continue
        new_loops, changed = [], False
        for li, loop in enumerate(face.loops):
            coedges = []
            for ci, ce in enumerate(loop.coedges):
                out = _retime_one(fi, ce, model.edges[ce.edge], surf, floor) if (li, ci) in todo else None
                if out is None:
                    coedges.append(ce)
                    continue
                pc, rec = out
                coedges.append(replace(ce, pcurve=pc))
                done.append(rec)
                changed = True
            new_loops.append(Loop(tuple(coedges), loop.outer))
        if changed:
            model.faces[fi] = Face(face.index, surf, face.surface_type, face.reversed, tuple(new_loops),
                                   face.uv_bounds, face.approximation)
    return done


def _mismatched(model: Model, face: Face, floor: float) -> set[tuple[int, int]]:
    """(loop, coedge) indices of the face's coedges whose S(pc(t)) stands farther than ``floor``
    from C(t) somewhere: one surface evaluation for all of the face's samples."""
    keys, ts, uvs, cs = [], [], [], []
    for li, loop in enumerate(face.loops):
        for ci, ce in enumerate(loop.coedges):
            edge = model.edges[ce.edge]
            if (ce.pcurve is None or edge.curve is None or edge.degenerate
                    or abs(ce.first - edge.first) + abs(ce.last - edge.last)
                    > 1e-12 * max(abs(edge.last - edge.first), 1e-300)):
                continue
            t = sample_params(edge.first, edge.last, [edge.curve.knots, ce.pcurve.knots])
            keys.append((li, ci))
            ts.append(len(t))
            uvs.append(ce.pcurve.evaluate(t))
            cs.append(edge.curve.evaluate(t))
    if not keys:
        return set()
    d = np.linalg.norm(face.surface.evaluate(np.concatenate(uvs)) - np.concatenate(cs), axis=1)
    worst = np.maximum.reduceat(d, np.r_[0, np.cumsum(ts)[:-1]])
    return {k for k, w in zip(keys, worst, strict=True) if w > floor}


def _compose(pc: BSplineCurve, tn: np.ndarray, sn: np.ndarray) -> BSplineCurve | None:
    """pc o phi exactly, for phi piecewise linear through the nodes (tn, sn) (both increasing, every
    knot of pc inside (sn_0, sn_-1) among the sn): one Bezier piece per node interval, C0 at the
    nodes. None when the nodes leave pc's domain."""
    p = pc.degree
    lo, hi = pc.domain
    if sn[0] < lo or sn[-1] > hi:
        return None
    breaks, segs = split_curve_at(pc.knots, p, pc.homogeneous(), sn)
    inside = (breaks[:-1] >= sn[0]) & (breaks[1:] <= sn[-1])
    segs = segs[inside]
    if len(segs) != len(sn) - 1:  # a knot of pc between two nodes: not one piece per interval
        return None
    H = np.concatenate([segs[0], *(seg[1:] for seg in segs[1:])])
    knots = np.concatenate([[tn[0]] * (p + 1), np.repeat(tn[1:-1], p), [tn[-1]] * (p + 1)])
    if pc.rational:
        return BSplineCurve(p, knots, H[:, :-1] / H[:, -1:], H[:, -1].copy())
    return BSplineCurve(p, knots, H)


def _retime_one(fi: int, ce: Coedge, edge, surf, floor: float):
    """A re-timed pcurve for one coedge, or None when it is same-parameter already, when its
    mismatch is mostly a gap, or when re-timing does not bring S(pc(t)) nearer to C(t)."""
    pc = ce.pcurve
    a, b = edge.first, edge.last
    ck = np.unique(edge.curve.knots)
    ck = ck[(ck > a) & (ck < b)]

    def trace(s):
        return surf.evaluate(pc.evaluate(s))

    t = np.union1d(sample_params(a, b, [edge.curve.knots, pc.knots]), ck)
    c = edge.curve.evaluate(t)
    before_d = np.linalg.norm(trace(t) - c, axis=1)
    before = float(before_d.max())
    if before <= floor:
        return None
    # the trace is nearer to C(t) than S(pc(t)) is, so only samples off by at least
    # before / TIMING_FACTOR can show a gap that large: project those first
    sel = before_d >= before / TIMING_FACTOR
    if np.linalg.norm(trace(_phi(t[sel], c[sel], trace, t)) - c[sel], axis=1).max() * TIMING_FACTOR >= before:
        return None
    s = _monotone(t, _phi(t, c, trace))
    near = np.linalg.norm(trace(s) - c, axis=1)  # distance of C(t) from the trace
    trace_gap = float(near.max())
    if before <= TIMING_FACTOR * trace_gap:
        return None
    # nodes: the edge curve's knots where phi was measured, and each pcurve knot at phi^-1 (so
    # every piece stays inside one pcurve span). C's knots are cuts of the edge plan already; a
    # pcurve knot that moves becomes a new one. More nodes would bring S(pc(t)) nearer to C(t)
    # between them, but every node is a cut across the face: refined to twice the trace's
    # distance, gmsh__917_fusee.step got 17 % more patches and no fewer I4 failures.
    pk = np.unique(pc.knots)
    pk = pk[(pk > a) & (pk < b)]
    tk = _snap(np.interp(pk, s, t), pk, ck, edge.curve, floor)
    free_ck = ~np.isin(ck, tk)
    tn = np.concatenate([[a], ck[free_ck], tk, [b]])
    sn = np.concatenate([[a], s[np.searchsorted(t, ck[free_ck])], pk, [b]])
    fixed = np.concatenate([[True], np.zeros(int(free_ck.sum()), bool), np.ones(len(pk), bool), [True]])
    order = np.lexsort((~fixed, tn))
    nodes = _strict(tn[order], sn[order], fixed[order], 1e-9 * (b - a))
    if nodes is None:
        return None
    tn, sn, _ = nodes
    new = _compose(pc, tn, sn)
    if new is None:
        return None
    tt = np.union1d(t, 0.5 * (tn[:-1] + tn[1:]))
    after = float(np.linalg.norm(surf.evaluate(new.evaluate(tt)) - edge.curve.evaluate(tt), axis=1).max())
    if after >= before:
        return None
    return new, Retimed(fi, ce.edge, before, after, trace_gap, len(tn) - 2)


def _snap(tk: np.ndarray, pk: np.ndarray, ck: np.ndarray, curve: BSplineCurve, within: float) -> np.ndarray:
    """Node parameters for the pcurve knots ``pk``, first guessed at ``tk`` = phi^-1(pk).

    Where re-timing hardly moves a knot (C(pk) within ``within`` of C(tk)) it stays at pk, and
    otherwise it moves onto a knot of the edge curve (``ck``) within ``within``, one node per knot.
    Pcurves that were nearly same-parameter had their knots at the edge's parameters, shared with
    the other face's pcurve and with C; re-timed, each face's knots would land a hair apart and
    leave cuts a sliver apart (the timing this gives up is within ``within``)."""
    out = tk.copy()
    if not len(tk):
        return out
    stay = np.linalg.norm(curve.evaluate(pk) - curve.evaluate(tk), axis=1) <= within
    out[stay] = pk[stay]
    if not len(ck):
        return out
    j = np.clip(np.searchsorted(ck, tk), 1, len(ck)) - 1
    j = np.where((j + 1 < len(ck)) & (np.abs(ck[np.minimum(j + 1, len(ck) - 1)] - tk) < np.abs(ck[j] - tk)),
                 j + 1, j)
    close = ~stay & (np.linalg.norm(curve.evaluate(tk) - curve.evaluate(ck[j]), axis=1) <= within)
    taken = set(np.flatnonzero(np.isin(ck, out[stay])).tolist())
    for i in np.flatnonzero(close):
        if j[i] not in taken:
            taken.add(int(j[i]))
            out[i] = ck[j[i]]
    return out


def _strict(tn, sn, fixed, width):
    """Drop free nodes until t and s both increase by more than ``width`` from node to node (the
    pcurve-knot nodes and the ends stay: a piece must not straddle a pcurve knot)."""
    keep = np.ones(len(tn), bool)
    last = 0
    for i in range(1, len(tn)):
        ok = tn[i] - tn[last] > width and sn[i] - sn[last] > width
        if ok:
            last = i
        elif not fixed[i]:
            keep[i] = False
        elif not fixed[last]:
            keep[last] = False
            last = i
        else:
            return None  # two pcurve knots (or an end) closer than width in t: no clean pieces
    return tn[keep], sn[keep], fixed[keep]
