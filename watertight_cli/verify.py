"""The own verify step of stage 1 (numpy only): is every patch where its face is?

Three independent checks per face, each against the input's own arrays, not against the
intermediate Bezier pieces that built the patches:

* **deviation**: every patch on a grid of (s, t) against the surface B-spline evaluated (scipy) at
  the exact cell map phi(s, t); must stay within the patch's bound plus ``exact_rel`` x diagonal.
* **trimming sides**: the patch's side on a trimming edge against S(pcurve(w)), with w running
  affinely over the piece's edge parameters, the pcurve evaluated as the B-spline it is in the
  input. This is the property stage 2 relies on.
* **area**: the summed patch areas (Gauss-Legendre on the patches) against the trimmed face's area
  measured by the kernel (passed in, as OCCT is not imported here), allowing 1e-5 of the area,
  the area a patch boundary sweeps when it moves by its bound (boundary length x bound, summed
  over the patches), measured from the interval between the kernel's two integrators.
* **folds**: the patch normal against the surface normal at the mapped points; a patch that turns
  over has a negative product somewhere.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from .core.bernstein import basis
from .model import Model
from .tolerances import Tolerances
from .untrim import FaceResult, Patch, UntrimResult, cell_map, patch_points

__all__ = ["FaceCheck", "Verification", "verify_untrim", "side_deviations"]

_GRID = 9  # samples per direction for the deviation and fold checks
_ENDS = np.array([0.0, 1.0])  # with _SIDE_S: a patch's four sides for the thin check (``thin_sides``)
_SIDE = 33  # samples along each trimming side
_SIDE_S = np.linspace(0.0, 1.0, _SIDE)
_GAUSS = 24  # Gauss-Legendre nodes per direction for areas
#: relative slack of the area check: OCCT's integrators are off by a few 1e-6 of the area even when
#: they agree with each other (measured on a face with a pole in gmsh__917_fusee.stp, where our
#: converged quadrature is 2.6e-6 from the nearer one); a missing or doubled cell is far larger
_AREA_REL = 1e-5
_GAUSS_X = 0.5 * (np.polynomial.legendre.leggauss(_GAUSS)[0] + 1)
_GAUSS_W = 0.5 * np.polynomial.legendre.leggauss(_GAUSS)[1]
_CHUNK = 256  # patches measured together (keeps the temporaries of the thin check near 25 MB)
_GRIDS = {
    "gauss": _GAUSS_X,
    "interior": np.linspace(0.05, 0.95, _GRID),  # fold check: away from collapsed rungs and poles
    "grid": np.linspace(0.0, 1.0, _GRID),  # deviation check
    "side": _SIDE_S,  # with "ends": a patch's four sides, for the thin check
    "ends": _ENDS,
}

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
    # patches narrower than the tolerance all along and longer than ten times it (I5: "no slivers
    # below the tolerance"): counted and reported, not a failure (see ``thin_patch``)
    thin: int = 0
    problems: list[str] = field(default_factory=list)
    # per patch, the largest distance of its trimming sides from S(pcurve) (0 without one); stage 2
    # takes it as the stage-1 patch's own deviation near sides that the loop closure moved
    side_per_patch: np.ndarray = field(default_factory=lambda: np.zeros(0))

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


@functools.lru_cache(maxsize=256)
def _bases(k: int, grid: str) -> tuple[np.ndarray, np.ndarray]:
    """Bernstein values and derivatives of degree k on one of the fixed sample grids."""
    x = _GRIDS[grid]
    b = basis(k, x)
    if k == 0:
        return b, np.zeros((len(x), 1))
    lower = basis(k - 1, x)
    return b, k * (np.pad(lower, ((0, 0), (1, 0))) - np.pad(lower, ((0, 0), (0, 1))))


@dataclass
class _Measures:
    """Per patch of a face (first axis): the samples and sizes the verify step compares."""

    grid: np.ndarray  # (P, _GRID, _GRID, 3) points on the grid g x g
    along_s: np.ndarray  # (P, _SIDE, 2, 3) the sides t = 0 and t = 1 sampled along s
    along_t: np.ndarray  # (P, 2, _SIDE, 3) the sides s = 0 and s = 1 sampled along t
    normals: np.ndarray  # (P, _GRID * _GRID, 3) unnormalized normals on the interior grid
    extent: np.ndarray  # (P,) largest coordinate range of the control net
    area: np.ndarray  # (P,) by tensor Gauss-Legendre quadrature (``_GAUSS`` nodes per direction)
    perimeter: np.ndarray  # (P,) length bound of the boundary: its four boundary control polygons


def _tensor(Bs: np.ndarray, C: np.ndarray, Bt: np.ndarray) -> np.ndarray:
    """sum_ij Bs[a, i] C[p, i, j] Bt[b, j] for P nets C (P, m+1, n+1, d) -> (P, a, b, d), as two
    matmuls."""
    P, m1, n1, d = C.shape
    X = (Bs @ C.reshape(P, m1, n1 * d)).reshape(P, -1, n1, d)
    return Bt[None, None] @ X


def _measures(patches: list[Patch]) -> _Measures:
    """The per-patch samples of ``_check_face`` for all patches of a face, computed for the patches
    of one bidegree and kind together (a few small array operations per patch and sample kind
    were most of the verify step's time)."""
    P = len(patches)
    out = _Measures(np.zeros((P, _GRID, _GRID, 3)), np.zeros((P, _SIDE, 2, 3)), np.zeros((P, 2, _SIDE, 3)),
                    np.zeros((P, _GRID * _GRID, 3)), np.zeros(P), np.zeros(P), np.zeros(P))
    groups: dict[tuple, list[int]] = {}
    for k, p in enumerate(patches):
        groups.setdefault((p.ctrl.shape, p.rational), []).append(k)
    for (shape, rational), members in groups.items():
        for lo in range(0, len(members), _CHUNK):
            idx = members[lo:lo + _CHUNK]
            C = np.stack([patches[k].ctrl for k in idx])
            m, n = shape[0] - 1, shape[1] - 1
            cart = (lambda h: h[..., :3] / h[..., 3:4]) if rational else (lambda h: h)  # noqa: E731
            b = {name: (_bases(m, name)[0], _bases(n, name)[0]) for name in ("grid", "side", "ends")}
            out.grid[idx] = cart(_tensor(b["grid"][0], C, b["grid"][1]))
            out.along_s[idx] = cart(_tensor(b["side"][0], C, b["ends"][1]))
            out.along_t[idx] = cart(_tensor(b["ends"][0], C, b["side"][1]))
            _, ps, pt = _derivs(C, rational, "interior")
            out.normals[idx] = np.cross(ps, pt).reshape(len(idx), -1, 3)
            _, ps, pt = _derivs(C, rational, "gauss")
            out.area[idx] = (_GAUSS_W @ np.linalg.norm(np.cross(ps, pt), axis=-1)) @ _GAUSS_W
            X = C[..., :3] / C[..., 3:4] if rational else C
            out.extent[idx] = np.ptp(X.reshape(len(idx), -1, 3), axis=1).max(axis=1)
            rows = (X[:, :, 0], X[:, :, -1], X[:, 0, :], X[:, -1, :])
            lengths = [np.linalg.norm(np.diff(r, axis=1), axis=-1).sum(axis=1) for r in rows]
            out.perimeter[idx] = ((lengths[0] + lengths[1]) + lengths[2]) + lengths[3]
    return out


def _derivs(C: np.ndarray, rational: bool, grid: str):
    """Points and first partial derivatives of P nets (P, m+1, n+1, d) on the grid x grid."""
    m, n = C.shape[1] - 1, C.shape[2] - 1
    (Bs, dBs), (Bt, dBt) = _bases(m, grid), _bases(n, grid)
    h, hs, ht = _tensor(Bs, C, Bt), _tensor(dBs, C, Bt), _tensor(Bs, C, dBt)
    if not rational:
        return h, hs, ht
    w, ws, wt = h[..., 3:], hs[..., 3:], ht[..., 3:]
    p = h[..., :3] / w
    return p, (hs[..., :3] - p * ws) / w, (ht[..., :3] - p * wt) / w


def _trimming_sides(patches: list[Patch]) -> list[tuple[int, object, float]]:
    """(patch index, side, t) of every side that lies on a pcurve piece (not a pole)."""
    return [(k, side, t) for k, p in enumerate(patches) for side, t in ((p.bottom, 0.0), (p.top, 1.0))
            if side.pcurve is not None and not side.degenerate]


def _side_uv(sides) -> np.ndarray:
    """The input's pcurve at ``_SIDE`` parameters per side, w affine over the piece's edge range."""
    s = _SIDE_S
    return (np.concatenate([side.pcurve.evaluate(side.w0 + s * (side.w1 - side.w0)) for _, side, _ in sides])
            if sides else np.zeros((0, 2)))


def _side_distances(patches: list[Patch], sides, on_side: np.ndarray) -> list[float]:
    """Per side: the largest distance between the patch's side and S(pcurve(w)) (``on_side``)."""
    refs = on_side.reshape(len(sides), _SIDE, 3)
    side = lambda k, t: patch_points(patches[k], _SIDE_S, np.array([t]))[:, 0, :]  # noqa: E731
    return [float(np.linalg.norm(side(k, t) - ref, axis=-1).max())
            for (k, _, t), ref in zip(sides, refs, strict=True)]


def side_deviations(fr: FaceResult, model: Model) -> np.ndarray:
    """Per patch of a stage-1 face, how far its trimming sides lie from the input's boundary
    S(pcurve(w)), sampled (0 for a patch without one). Where the loop closure moved a side, this
    is what the move left near it, measured; the face's ``closure`` bounds it for every patch.
    The verify step records the same per patch (``FaceCheck.side_per_patch``)."""
    out = np.zeros(len(fr.patches))
    sides = _trimming_sides(fr.patches)
    if sides:
        on_side = model.faces[fr.face].surface.evaluate(_side_uv(sides))
        for (k, _, _), d in zip(sides, _side_distances(fr.patches, sides, on_side), strict=True):
            out[k] = max(out[k], d)
    return out


def _check_face(fr: FaceResult, model: Model, tol: Tolerances,
                area_ref: tuple[float, float] | None = None) -> FaceCheck:
    face = model.faces[fr.face]
    surf = face.surface
    slack = tol.exact_rel * model.diagonal
    g = _GRIDS["grid"]
    gi = _GRIDS["interior"]
    problems: list[str] = list(fr.problems)
    u0, u1, v0, v1 = face.uv_bounds
    h = 1e-6 * np.array([max(u1 - u0, 1e-300), max(v1 - v0, 1e-300)])
    patches = fr.patches
    for k, p in enumerate(patches):
        if max(p.degrees) > tol.max_degree:
            problems.append(f"face {fr.face} patch {k}: degree {p.degrees} above the maximum "
                            f"{tol.max_degree}")
    # one surface evaluation per kind of sample for the whole face (building the B-spline
    # evaluator costs more than evaluating it)
    uv_grid = np.stack([cell_map(p, g, g) for p in patches]).reshape(-1, 2) if patches else np.zeros((0, 2))
    uv_in = np.stack([cell_map(p, gi, gi) for p in patches]).reshape(-1, 2) if patches else np.zeros((0, 2))
    sides = _trimming_sides(patches)
    uv_side = _side_uv(sides)
    ev = surf.evaluate(np.concatenate([uv_grid, uv_side, uv_in + [h[0], 0], uv_in - [h[0], 0],
                                       uv_in + [0, h[1]], uv_in - [0, h[1]]]))
    n1, n2 = len(uv_grid), len(uv_side)
    on_grid = ev[:n1].reshape(len(patches), _GRID, _GRID, 3)
    on_side = ev[n1:n1 + n2].reshape(len(sides), _SIDE, 3)
    fd = ev[n1 + n2:].reshape(4, len(patches), _GRID * _GRID, 3)
    n_surf = np.cross(fd[0] - fd[1], fd[2] - fd[3])
    n_scale = float(np.linalg.norm(n_surf, axis=-1).max()) if patches else 0.0

    dev = side_dev = area_out = swept = 0.0
    folded = collapsed = thin = 0
    rung_eps = 1e-12 * max(u1 - u0, v1 - v0)
    m = _measures(patches)
    for k, p in enumerate(patches):
        d = float(np.max(np.linalg.norm(m.grid[k] - on_grid[k], axis=-1)))
        dev = max(dev, d)
        if d > p.bound + slack:
            problems.append(f"face {fr.face} patch {k}: deviation {d:.3g} exceeds its bound {p.bound:.3g}")
        # folds: patch normal against the surface normal at the same points (interior samples),
        # only where both normals are meaningful: not at the surface's poles or creases (tiny
        # against the face's largest normal) and not where the patch itself degenerates
        n_patch = m.normals[k]
        live = ((np.linalg.norm(n_surf[k], axis=1) > 1e-6 * n_scale)
                & (np.linalg.norm(n_patch, axis=1) > 1e-8 * m.extent[k] ** 2))
        if np.any(np.sum(n_patch * n_surf[k], axis=1)[live] <= 0.0):
            folded += 1
            problems.append(f"face {fr.face} patch {k}: folded (its normal turns against the surface's)")
        # rungs of zero length away from poles (triangular cells of the slab decomposition)
        for a in (0, -1):
            pa = p.bottom.H[a, :2] / p.bottom.H[a, 2]
            pb = p.top.H[a, :2] / p.top.H[a, 2]
            if float(np.abs(pa - pb).max()) <= rung_eps:  # (np.allclose cost 80 us a call)
                collapsed += 1
        area_out += float(m.area[k])
        # a boundary that moves by the bound sweeps at most perimeter x bound of area
        swept += float(m.perimeter[k]) * (p.bound + fr.closure)
    if patches:
        thin = int(thin_sides_many(m.along_s, m.along_t, tol.approx_rel * model.diagonal).sum())
    # trimming sides against S(pcurve(w))
    per_patch = np.zeros(len(patches))
    for (k, side, _), d in zip(sides, _side_distances(patches, sides, on_side), strict=True):
        p = patches[k]
        side_dev = max(side_dev, d)
        per_patch[k] = max(per_patch[k], d)
        if d > p.bound + fr.closure + slack:
            problems.append(f"face {fr.face} patch {k}: side on edge {side.edge} is {d:.3g} from "
                            f"S(pcurve), bound {p.bound + fr.closure:.3g}")
    area_in = None
    if area_ref is not None:
        area_in = area_ref[0]
        lo, hi = min(area_ref), max(area_ref)
        allowed = _AREA_REL * hi + swept
        off = max(lo - area_out, area_out - hi, 0.0)  # distance from the kernel's interval
        if off > allowed:
            problems.append(f"face {fr.face}: patch area {area_out:.9g} is {off:.3g} outside the kernel's "
                            f"[{lo:.9g}, {hi:.9g}], more than {allowed:.3g}")
    if not fr.patches and not fr.problems:
        problems.append(f"face {fr.face}: no patches")
    return FaceCheck(fr.face, len(fr.patches), fr.bound, dev, side_dev, area_in, area_out, folded,
                     collapsed, thin, problems, per_patch)


def thin_patch(pts: np.ndarray, width: float) -> bool:
    """A patch sampled on a grid (n, n, 3) is thin when its opposite sides stand less than ``width``
    apart at three quarters of their samples or more (across s and across t, whichever is
    narrower) while it is more than ten times that long: a sliver below the tolerance (I5).
    Across means from a sample of one side to the nearest point of the opposite side's polyline,
    not to the sample of the same parameter, and a quarter of the samples may stand farther: a
    strip whose end runs slanted along it (a pcurve piece nearly on a slab line, between its
    extremum and a knot 6e-5 away in v: bspline_boolean face 0, 3e-6 wide and 33 long) has that
    end's corners 0.0035 apart, and one side runs on past the other's end by as much. Triangles
    at poles are not thin: their collapsed side stands the whole patch away from the opposite
    one."""
    return thin_sides(pts[:, [0, -1]], pts[[0, -1], :], width)


def thin_sides(along_s: np.ndarray, along_t: np.ndarray, width: float) -> bool:
    """``thin_patch`` on the sides alone: ``along_s`` (k, 2, 3) the sides t = 0 and t = 1 sampled
    along s, ``along_t`` (2, k, 3) the sides s = 0 and s = 1 sampled along t. Dense samples keep
    the polylines' sagitta below the widths measured (9 along a curved rung 33 long: 1.4e-4)."""
    return bool(thin_sides_many(along_s[None], along_t[None], width)[0])


def thin_sides_many(along_s: np.ndarray, along_t: np.ndarray, width: float) -> np.ndarray:
    """``thin_sides`` of many patches at once: ``along_s`` (P, k, 2, 3), ``along_t`` (P, 2, k, 3);
    (P,) bool. (One patch at a time, the check was half of stage 1's verify step: 41864 calls of
    a few small array operations each on occt__bug24595's 10466 patches.) The measured ones are
    taken in chunks of ``_CHUNK`` patches, which keeps the temporaries near 25 MB."""
    long_s = np.linalg.norm(np.diff(along_s, axis=1), axis=-1).sum(axis=1).max(axis=-1)
    long_t = np.linalg.norm(np.diff(along_t, axis=2), axis=-1).sum(axis=2).max(axis=-1)
    # opposite sides whose bounding boxes stand ``width`` apart are that far apart everywhere: only
    # patches with a pair of sides nearer than that are measured (a few of a face's patches)
    near = ((_box_gap(along_s[:, :, 0], along_s[:, :, 1]) < width)
            | (_box_gap(along_t[:, 0], along_t[:, 1]) < width))
    out = np.zeros(len(along_s), dtype=bool)
    todo = np.flatnonzero(near & (np.maximum(long_s, long_t) > 10.0 * width))
    for lo in range(0, len(todo), _CHUNK):
        k = todo[lo:lo + _CHUNK]
        out[k] = _thin_measured(along_s[k], along_t[k], width)
    return out


def _box_gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance between the bounding boxes of the point sets a and b (P, k, 3); (P,)."""
    gap = np.maximum(np.maximum(b.min(axis=1) - a.max(axis=1), a.min(axis=1) - b.max(axis=1)), 0.0)
    return np.linalg.norm(gap, axis=-1)


def _thin_measured(along_s: np.ndarray, along_t: np.ndarray, width: float) -> np.ndarray:
    """``thin_sides_many``'s measure of the widths across (the lengths already checked)."""
    across_t = np.maximum(_side_gap(along_s[:, :, 0], along_s[:, :, 1]),
                          _side_gap(along_s[:, :, 1], along_s[:, :, 0]))
    across_s = np.maximum(_side_gap(along_t[:, 0], along_t[:, 1]), _side_gap(along_t[:, 1], along_t[:, 0]))
    return np.minimum(across_t, across_s) < width


def _side_gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The distance from the points of ``a`` (P, k, 3) to the polyline through ``b`` (P, m, 3) that
    three quarters of them keep within; (P,)."""
    p, q = b[:, :-1], b[:, 1:]
    d = q - p
    dd = np.maximum(np.einsum("pij,pij->pi", d, d), 1e-300)
    t = np.clip(np.einsum("pkij,pij->pki", a[:, :, None, :] - p[:, None], d) / dd[:, None], 0.0, 1.0)
    foot = p[:, None] + t[..., None] * d[:, None]
    return np.quantile(np.linalg.norm(a[:, :, None, :] - foot, axis=-1).min(axis=2), 0.75, axis=1)


def verify_untrim(model: Model, result: UntrimResult, tol: Tolerances,
                  areas: np.ndarray | None = None, progress=None) -> Verification:
    """Check every face of a stage-1 result (see module doc). ``areas``: (faces, 2) the kernel's
    two face areas (see ``occ.build.face_area``), or None to skip the area check."""
    checks = []
    for fr in result.faces:
        ref = None if areas is None else (float(areas[fr.face, 0]), float(areas[fr.face, 1]))
        checks.append(_check_face(fr, model, tol, ref))
        if progress is not None:
            progress(1)
    return Verification(checks)
