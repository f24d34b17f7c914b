"""The own verify step of stage 1 (numpy only): is every patch where its face is?

Three independent checks per face, each against the input's own arrays, not against the
intermediate Bezier pieces that built the patches:

* **deviation**: every patch on a grid of (s, t) against the surface B-spline evaluated (scipy) at
  the exact cell map phi(s, t); must stay within the patch's bound plus ``exact_rel`` x diagonal.
* **trimming sides**: the patch's side on a trimming edge against S(pcurve(w)), with w running
  affinely over the piece's edge parameters, the pcurve evaluated as the B-spline it is in the
  input. This is the property stage 2 relies on.
* **area**: the summed patch areas (Gauss-Legendre on the patches) against the trimmed face's area
  measured by the kernel (passed in, as OCCT is not imported here), allowing 1e-6 of the area,
  the deviation bound times a perimeter scale, and the spread of the kernel's two integrators.
* **folds**: the patch normal against the surface normal at the mapped points; a patch that turns
  over has a negative product somewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .core.bernstein import basis
from .model import Model
from .tolerances import Tolerances
from .untrim import FaceResult, Patch, UntrimResult, cell_map, patch_points

__all__ = ["FaceCheck", "Verification", "verify_untrim", "patch_area"]

_GRID = 9  # samples per direction for the deviation and fold checks
_SIDE = 33  # samples along each trimming side
_GAUSS = 24  # Gauss-Legendre nodes per direction for areas


@dataclass
class FaceCheck:
    face: int
    patches: int
    bound: float  # guaranteed (or estimated) deviation bound, model units
    deviation: float  # sampled deviation from the exact cell maps
    side_deviation: float  # sampled deviation of trimming sides from S(pcurve)
    area_in: float | None
    area_out: float
    folded: int  # patches whose normal turns against the surface's
    collapsed_rungs: int  # cells with a rung of zero length that is not at a pole
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


@dataclass
class Verification:
    faces: list[FaceCheck]

    @property
    def ok(self) -> bool:
        return all(f.ok for f in self.faces)

    @property
    def problems(self) -> list[str]:
        return [p for f in self.faces for p in f.problems]


def _derivs(patch: Patch, s: np.ndarray, t: np.ndarray):
    """Points and first partial derivatives of a patch on the grid s x t."""
    C = patch.ctrl
    m, n = C.shape[0] - 1, C.shape[1] - 1

    def dbasis(k, x):
        if k == 0:
            return np.zeros((len(x), 1))
        return k * (np.pad(basis(k - 1, x), ((0, 0), (1, 0))) - np.pad(basis(k - 1, x), ((0, 0), (0, 1))))

    Bs, Bt, dBs, dBt = basis(m, s), basis(n, t), dbasis(m, s), dbasis(n, t)
    h = np.einsum("ai,ijd,bj->abd", Bs, C, Bt)
    hs = np.einsum("ai,ijd,bj->abd", dBs, C, Bt)
    ht = np.einsum("ai,ijd,bj->abd", Bs, C, dBt)
    if not patch.rational:
        return h, hs, ht
    w, ws, wt = h[..., 3:], hs[..., 3:], ht[..., 3:]
    p = h[..., :3] / w
    return p, (hs[..., :3] - p * ws) / w, (ht[..., :3] - p * wt) / w


def patch_area(patch: Patch, nodes: int = _GAUSS) -> float:
    x, wq = np.polynomial.legendre.leggauss(nodes)
    x, wq = 0.5 * (x + 1), 0.5 * wq
    _, ps, pt = _derivs(patch, x, x)
    return float(np.einsum("a,b,ab->", wq, wq, np.linalg.norm(np.cross(ps, pt), axis=-1)))


def _surface_normals(surface, uv: np.ndarray, h: np.ndarray) -> np.ndarray:
    du = np.array([h[0], 0.0])
    dv = np.array([0.0, h[1]])
    su = surface.evaluate(uv + du) - surface.evaluate(uv - du)
    sv = surface.evaluate(uv + dv) - surface.evaluate(uv - dv)
    return np.cross(su, sv)


def _check_face(fr: FaceResult, model: Model, tol: Tolerances, area_in: float | None,
                area_spread: float = 0.0) -> FaceCheck:
    face = model.faces[fr.face]
    surf = face.surface
    slack = tol.exact_rel * model.diagonal
    g = np.linspace(0.0, 1.0, _GRID)
    gi = np.linspace(0.05, 0.95, _GRID)
    dev = side_dev = area_out = 0.0
    folded = collapsed = 0
    problems: list[str] = list(fr.problems)
    u0, u1, v0, v1 = face.uv_bounds
    h = 1e-6 * np.array([max(u1 - u0, 1e-300), max(v1 - v0, 1e-300)])
    for k, p in enumerate(fr.patches):
        if max(p.degrees) > tol.max_degree:
            problems.append(f"face {fr.face} patch {k}: degree {p.degrees} above the maximum "
                            f"{tol.max_degree}")
        # deviation from S(phi)
        P = patch_points(p, g, g)
        Q = surf.evaluate(cell_map(p, g, g).reshape(-1, 2)).reshape(P.shape)
        d = float(np.max(np.linalg.norm(P - Q, axis=-1)))
        dev = max(dev, d)
        if d > p.bound + slack:
            problems.append(f"face {fr.face} patch {k}: deviation {d:.3g} exceeds its bound {p.bound:.3g}")
        # trimming sides against S(pcurve(w))
        s = np.linspace(0.0, 1.0, _SIDE)
        for side, t in ((p.bottom, 0.0), (p.top, 1.0)):
            if side.pcurve is None or side.degenerate:
                continue
            w = side.w0 + s * (side.w1 - side.w0)
            ref = surf.evaluate(side.pcurve.evaluate(w))
            got = patch_points(p, s, np.array([t]))[:, 0, :]
            d = float(np.max(np.linalg.norm(got - ref, axis=-1)))
            side_dev = max(side_dev, d)
            if d > p.bound + fr.closure + slack:
                problems.append(f"face {fr.face} patch {k}: side on edge {side.edge} is {d:.3g} from "
                                f"S(pcurve), bound {p.bound + fr.closure:.3g}")
        # folds: patch normal against the surface normal at the same points (interior samples)
        _, ps, pt = _derivs(p, gi, gi)
        n_patch = np.cross(ps, pt).reshape(-1, 3)
        n_surf = _surface_normals(surf, cell_map(p, gi, gi).reshape(-1, 2), h)
        scale = np.linalg.norm(n_patch, axis=1) * np.linalg.norm(n_surf, axis=1)
        live = scale > 1e-12 * max(float(scale.max()), 1e-300)
        if np.any(np.sum(n_patch * n_surf, axis=1)[live] <= 0.0):
            folded += 1
            problems.append(f"face {fr.face} patch {k}: folded (its normal turns against the surface's)")
        # rungs of zero length away from poles (triangular cells of the slab decomposition)
        for a, b in ((0, 0), (-1, -1)):
            pa = p.bottom.H[a, :2] / p.bottom.H[a, 2]
            pb = p.top.H[b, :2] / p.top.H[b, 2]
            if np.allclose(pa, pb, rtol=0.0, atol=1e-12 * max(u1 - u0, v1 - v0)):
                collapsed += 1
        area_out += patch_area(p)
    if area_in is not None and area_in > 0:
        perimeter = 4.0 * np.sqrt(area_in)  # of a square of the same area: a scale, not a bound
        allowed = 1e-6 * area_in + 2.0 * perimeter * fr.bound + area_spread
        if abs(area_out - area_in) > allowed:
            problems.append(f"face {fr.face}: patch area {area_out:.9g} differs from the face area "
                            f"{area_in:.9g} by more than {allowed:.3g}")
    if not fr.patches and not fr.problems:
        problems.append(f"face {fr.face}: no patches")
    return FaceCheck(fr.face, len(fr.patches), fr.bound, dev, side_dev, area_in, area_out, folded,
                     collapsed, problems)


def verify_untrim(model: Model, result: UntrimResult, tol: Tolerances,
                  areas: np.ndarray | None = None, progress=None) -> Verification:
    """Check every face of a stage-1 result (see module doc). ``areas``: (faces, 2) kernel face areas
    and their uncertainty (see ``occ.build.face_area``), or None to skip the area check."""
    checks = []
    for fr in result.faces:
        ref = (None, 0.0) if areas is None else (float(areas[fr.face, 0]), float(areas[fr.face, 1]))
        checks.append(_check_face(fr, model, tol, *ref))
        if progress is not None:
            progress(1)
    return Verification(checks)
