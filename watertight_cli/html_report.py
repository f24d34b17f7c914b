"""Self-contained HTML pages of ``watertight report`` and ``watertight convert`` (``--html``).

Pure numpy and matplotlib (Agg, offscreen): the pages are built from report dicts and
:class:`Scene` arrays (triangles and line segments, made by ``watertight_cli.scene``). Every figure
is embedded as a base64 ``data:`` image (PNG for the 3D pictures, SVG for charts); the page has
no external reference at all (no URL, font, stylesheet or script), so it works offline and can be
attached to a CI run. Written atomically (temporary file in the target folder, then rename).
"""

from __future__ import annotations

import base64
import contextlib
import html
import io
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import OutputError
from .meshcheck import describe

MAX_TRIANGLES = 20_000  # per picture, after decimation
MAX_EDGE_SEGMENTS = 4_000  # gap-coloured edge segments per picture (worst edges first)
MAX_LINE_SEGMENTS = 3_000  # patch-boundary segments per picture (a fixed random subset)
WORST_ROWS = 20
VIEWS = (("isometric", 28.0, -58.0), ("front (-y)", 0.0, -90.0), ("top (+z)", 90.0, -90.0))


@dataclass
class Scene:
    """What one 3D picture draws.

    triangles : (T, 3, 3) float, the surface as a triangle soup
    groups : (T,) int, per triangle the source face (its colour)
    edges : (S, 2, 3) float, model edges as segments, coloured by ``edge_values`` (gap) when given
    edge_values : (S,) float or None
    lines : (L, 2, 3) float, thin dark segments (patch boundaries after conversion)
    marks : (k, 3) float, numbered markers (the worst edges' worst samples, in table order)
    notes : what was left out or decimated, for the caption
    """

    triangles: np.ndarray
    groups: np.ndarray
    edges: np.ndarray
    edge_values: np.ndarray | None = None
    lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    marks: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    notes: list[str] = field(default_factory=list)


# ------------------------------------------------------------------------------------ matplotlib


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _data_uri(fig, fmt: str, dpi: int = 100) -> str:
    buf = io.BytesIO()
    meta = {"Software": None} if fmt == "png" else {"Creator": None, "Date": None}
    fig.savefig(buf, format=fmt, dpi=dpi, metadata=meta, bbox_inches="tight")
    _pyplot().close(fig)
    mime = "image/png" if fmt == "png" else "image/svg+xml"
    return f"data:{mime};base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(uri: str, caption: str, alt: str) -> str:
    return (f'<figure><img src="{uri}" alt="{html.escape(alt)}">'
            f"<figcaption>{caption}</figcaption></figure>")


# ------------------------------------------------------------------------------------ decimation


def _cluster(pts: np.ndarray, lo: np.ndarray, cell: float):
    """Cell id per point, the triangles' cell ids, and the indices of the surviving triangles."""
    keys = np.floor((pts - lo) / cell).astype(np.int64)
    span = keys.max(axis=0) + 1
    cid = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, inv = np.unique(cid, return_inverse=True)
    t = inv.reshape(-1, 3)
    ok = np.flatnonzero((t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 0] != t[:, 2]))
    _, first = np.unique(np.sort(t[ok], axis=1), axis=0, return_index=True)
    return inv, t, ok[np.sort(first)]


def decimate(triangles: np.ndarray, groups: np.ndarray, max_triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``max_triangles`` triangles, by vertex clustering on a uniform grid.

    Vertices in one grid cell merge into their mean; triangles that collapse, and repeats, drop.
    The finest grid within the budget is searched by bisection on the cell size. The surface
    keeps its extent and has no holes bigger than a cell; each kept triangle keeps its group.
    """
    if len(triangles) <= max_triangles:
        return triangles, groups
    pts = triangles.reshape(-1, 3)
    lo = pts.min(axis=0)
    ext = float((pts.max(axis=0) - lo).max()) or 1.0
    fine, coarse = ext / 4000, ext / 2  # cell sizes: too many triangles / within budget
    best = _cluster(pts, lo, coarse)
    for _ in range(14):
        cell = np.sqrt(fine * coarse)
        trial = _cluster(pts, lo, cell)
        if len(trial[2]) <= max_triangles:
            coarse, best = cell, trial
        else:
            fine = cell
        if coarse / fine < 1.1:
            break
    inv, t, keep = best
    centers = np.zeros((inv.max() + 1, 3))
    np.add.at(centers, inv, pts)
    centers /= np.bincount(inv)[:, None]
    return centers[t[keep]], groups[keep]


def refine(triangles: np.ndarray, groups: np.ndarray, max_len: float,
           max_triangles: int, rounds: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Split triangles longer than ``max_len`` into four, while the count stays within budget.

    matplotlib sorts polygons by their centroids' depth (painter's algorithm); a planar face of a
    few huge triangles is then drawn over or under its neighbours wholesale. Even sizes fix that.
    """
    for _ in range(rounds):
        longest = np.max(np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2), axis=1)
        big = longest > max_len
        if not big.any() or len(triangles) + 3 * int(big.sum()) > max_triangles:
            break
        a, b, c = triangles[big, 0], triangles[big, 1], triangles[big, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        quads = ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))
        new = np.concatenate([np.stack(t, axis=1) for t in quads])
        triangles = np.concatenate([triangles[~big], new])
        groups = np.concatenate([groups[~big], np.tile(groups[big], 4)])
    return triangles, groups


def limit_segments(segments: np.ndarray, values: np.ndarray | None, most: int) -> tuple[np.ndarray, object]:
    """At most ``most`` segments: the largest values first, or a fixed random subset without values."""
    if len(segments) <= most:
        return segments, values
    if values is not None:
        keep = np.argsort(-values, kind="stable")[:most]
        return segments[keep], values[keep]
    keep = np.sort(np.random.default_rng(0).choice(len(segments), most, replace=False))
    return segments[keep], None


# ------------------------------------------------------------------------------------ figures


def gap_norm(*value_sets) -> tuple[float, float]:
    """(vmin, vmax) of a log colour scale covering the positive values of all sets."""
    pos = [v[v > 0] for v in value_sets if v is not None and len(v)]
    pos = [p for p in pos if len(p)]
    if not pos:
        return 1e-12, 1.0
    lo, hi = min(float(p.min()) for p in pos), max(float(p.max()) for p in pos)
    if hi <= lo:
        lo, hi = lo / 10, hi * 10
    return lo, hi


def gap_histogram(series: list[tuple[str, np.ndarray, str]], marks: list[tuple[str, float, str]]) -> str:
    """Histogram of per-edge gaps on a log x axis; one step outline per (label, values, colour),
    with vertical lines at the marks (label, value, colour). Returns an SVG data URI."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8.5, 3.6))
    lo, hi = gap_norm(*[v for _, v, _ in series])
    for _, x, _ in marks:
        if x > 0:
            lo, hi = min(lo, x), max(hi, x)
    bins = np.logspace(np.log10(lo) - 0.05, np.log10(hi) + 0.05, 60)
    for label, values, colour in series:
        values = np.asarray(values, dtype=float)
        zeros = int(np.sum(values <= 0))
        text = f"{label}: {len(values)} edges, max {values.max() if len(values) else 0:.3g}"
        if zeros:
            text += f" ({zeros} exactly 0, not drawn)"
        ax.hist(values[values > 0], bins=bins, histtype="stepfilled", alpha=0.35, color=colour)
        ax.hist(values[values > 0], bins=bins, histtype="step", color=colour, label=text, linewidth=1.4)
    for label, x, colour in marks:
        if x > 0:
            ax.axvline(x, color=colour, linestyle="--", linewidth=1.2, label=f"{label} = {x:.3g}")
    ax.set_xscale("log")
    ax.set_xlabel("gap per edge (mm, log scale)")
    if max((len(v) for _, v, _ in series), default=0) > 50:  # a few edges stay visible beside many
        ax.set_yscale("log")
        ax.set_ylabel("edges (log)")
    else:
        ax.set_ylabel("edges")
    ax.legend(fontsize=8, loc="upper left", frameon=False)
    ax.grid(True, which="major", alpha=0.25)
    return _data_uri(fig, "svg")


def _shade(triangles: np.ndarray, base: np.ndarray, elev: float, azim: float) -> np.ndarray:
    """Flat head-light shading: the base colours scaled by |normal . view direction|."""
    e, a = np.radians(elev), np.radians(azim)
    view = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    n = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(n, axis=1)
    length[length == 0] = 1.0
    lit = 0.35 + 0.65 * np.abs(n @ view) / length
    out = base.copy()
    out[:, :3] *= lit[:, None]
    return out


def face_colours(groups: np.ndarray, uniform: bool) -> np.ndarray:
    """RGBA per triangle: one light grey when ``uniform``, else a qualitative colour per group."""
    if uniform or len(groups) == 0:
        return np.tile([0.78, 0.80, 0.84, 1.0], (len(groups), 1))
    import matplotlib

    palette = np.array(matplotlib.colormaps["tab20"].colors)
    # spread neighbouring face numbers over the palette (7 is prime to 20)
    rgb = palette[(groups * 7) % len(palette)]
    return np.concatenate([0.2 + 0.8 * rgb, np.ones((len(groups), 1))], axis=1)


CLOSE_UP = 0.08  # half-size of the close-up box around the worst edge, relative to the model's extent


def _prepare(triangles, groups, edges, values, lines, max_triangles: int, notes: list[str] | None):
    """Budgeted arrays for one panel; ``notes`` (when given) says what was left out."""
    tris, grp = decimate(triangles, groups, max_triangles)
    if notes is not None and len(tris) < len(triangles):
        notes.append(f"surface decimated from {len(triangles)} to {len(tris)} triangles")
    if len(tris):
        flat = tris.reshape(-1, 3)
        tris, grp = refine(tris, grp, float((flat.max(axis=0) - flat.min(axis=0)).max()) / 30, max_triangles)
    kept, values = limit_segments(edges, values, MAX_EDGE_SEGMENTS)
    if notes is not None and len(kept) < len(edges):
        notes.append(f"{len(kept)} of {len(edges)} edge segments drawn (largest gaps first)")
    few, _ = limit_segments(lines, None, MAX_LINE_SEGMENTS)
    if notes is not None and len(few) < len(lines):
        notes.append(f"{len(few)} of {len(lines)} patch-boundary segments drawn (a random subset)")
    return tris, grp, kept, values, few


def clip_triangles(triangles: np.ndarray, groups: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_len: float,
                   budget: int) -> tuple[np.ndarray, np.ndarray]:
    """The triangles near the box [lo, hi], split until shorter than ``max_len`` (within budget),
    keeping at each split only the pieces that touch the box; finally those centred inside it."""
    for _ in range(30):
        touch = np.all(triangles.max(axis=1) >= lo, axis=1) & np.all(triangles.min(axis=1) <= hi, axis=1)
        triangles, groups = triangles[touch], groups[touch]
        longest = np.max(np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2), axis=1)
        big = longest > max_len
        if not big.any() or len(triangles) + 3 * int(big.sum()) > budget:
            break
        triangles, groups = refine(triangles, groups, max_len, len(triangles) + 3 * int(big.sum()), rounds=1)
    centre = triangles.mean(axis=1)
    inside = np.all((centre >= lo) & (centre <= hi), axis=1)
    return triangles[inside], groups[inside]


def clip_segments(segments: np.ndarray, values, lo: np.ndarray, hi: np.ndarray):
    """The parts of the segments (n, 2, 3) inside the box [lo, hi] (Liang-Barsky), with their values."""
    if not len(segments):
        return segments, values
    p, d = segments[:, 0], segments[:, 1] - segments[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - p) / d, (hi - p) / d
    t_in = np.where(d == 0, np.where((p >= lo) & (p <= hi), -np.inf, np.inf), np.minimum(ta, tb))
    t_out = np.where(d == 0, np.where((p >= lo) & (p <= hi), np.inf, -np.inf), np.maximum(ta, tb))
    t0 = np.maximum(t_in.max(axis=1), 0.0)
    t1 = np.minimum(t_out.min(axis=1), 1.0)
    keep = t0 < t1
    out = np.stack([p[keep] + t0[keep, None] * d[keep], p[keep] + t1[keep, None] * d[keep]], axis=1)
    return out, (None if values is None else values[keep])


def render(scene: Scene, title: str, norm_range: tuple[float, float] | None, per_face: bool,
           views=VIEWS, max_triangles: int = MAX_TRIANGLES) -> tuple[str, list[str]]:
    """The scene in several views side by side, plus a close-up around the worst edge's worst
    sample (marker 1) when there are marks; a PNG data URI and the caption notes."""
    plt = _pyplot()
    from matplotlib.colors import LogNorm
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    notes = list(scene.notes)
    whole = _prepare(scene.triangles, scene.groups, scene.edges, scene.edge_values, scene.lines,
                     max_triangles, notes)
    allpts = [a.reshape(-1, 3) for a in (whole[0], whole[2], whole[4]) if len(a)]
    pts = np.concatenate(allpts) if allpts else np.zeros((1, 3))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    size = max(float((hi - lo).max()), 1e-9)
    panels = [(name, elev, azim, whole, lo, hi) for name, elev, azim in views]
    if len(scene.marks):
        c, r = scene.marks[0], CLOSE_UP * size
        blo, bhi = c - r, c + r
        tris, groups = clip_triangles(scene.triangles, scene.groups, blo, bhi, r / 12, max_triangles // 2)
        edges, values = clip_segments(scene.edges, scene.edge_values, blo, bhi)
        lines, _ = clip_segments(scene.lines, None, blo, bhi)
        part = _prepare(tris, groups, edges, values, lines, max_triangles // 2, None)
        panels.append((f"close-up at 1 (box {2 * r:.3g} mm)", views[0][1], views[0][2], part, blo, bhi))
    norm = LogNorm(*norm_range) if norm_range else None
    cmap = plt.get_cmap("plasma")

    fig = plt.figure(figsize=(4.6 * len(panels) + 0.9, 4.6))
    fig.subplots_adjust(left=0.0, right=0.95, bottom=0.0, top=0.88, wspace=0.02)
    for k, (name, elev, azim, (tris, groups, edges, values, lines), plo, phi) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), k + 1, projection="3d", computed_zorder=False)
        ax.view_init(elev=elev, azim=azim)
        if len(tris):
            shaded = _shade(tris, face_colours(groups, uniform=not per_face), elev, azim)
            # edges in the face colour: no seams between triangles
            ax.add_collection3d(Poly3DCollection(tris, facecolors=shaded, edgecolors=shaded, linewidths=0.25,
                                                 zorder=1))
        if len(lines):
            ax.add_collection3d(Line3DCollection(lines, colors=(0.1, 0.1, 0.1, 0.45), linewidths=0.35,
                                                 zorder=2))
        if len(edges):
            if values is not None and norm is not None:
                colours = cmap(norm(np.clip(values, norm.vmin, norm.vmax)))
            else:
                colours = (0.15, 0.15, 0.15, 0.9)
            ax.add_collection3d(Line3DCollection(edges, colors=colours, linewidths=1.6, zorder=3))
        for i, p in enumerate(scene.marks):
            if np.all((p >= plo) & (p <= phi)):
                ax.scatter([p[0]], [p[1]], [p[2]], s=40, marker="o", facecolors="none", edgecolors="red",
                           linewidths=1.4, zorder=4)
                ax.text(p[0], p[1], p[2], f" {i + 1}", color="red", fontsize=8, zorder=5)
        ext = np.maximum(phi - plo, max(float((phi - plo).max()), 1e-12) * 0.05)
        mid = (plo + phi) / 2
        ax.set_xlim(mid[0] - ext[0] / 2, mid[0] + ext[0] / 2)
        ax.set_ylim(mid[1] - ext[1] / 2, mid[1] + ext[1] / 2)
        ax.set_zlim(mid[2] - ext[2] / 2, mid[2] + ext[2] / 2)
        # equal scale on the three axes; a long part fills the panel at zoom 1 already
        ax.set_box_aspect(tuple(ext), zoom=1.2 if ext.max() < 2 * np.median(ext) else 1.0)
        ax.set_axis_off()
        ax.set_title(name, fontsize=9)
    if norm is not None and scene.edge_values is not None:
        from matplotlib.cm import ScalarMappable

        cb = fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=fig.axes, fraction=0.02, pad=0.01)
        cb.set_label("edge gap (mm, log scale)", fontsize=8)
    fig.suptitle(title, fontsize=10)
    return _data_uri(fig, "png", dpi=90), notes


def distributions(rep: dict) -> str:
    """Degrees of the patches, patches per face and deviation per face (after convert): SVG URI."""
    plt = _pyplot()
    faces = rep.get("faces", [])
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    hist = {int(k): v for k, v in rep["degree"]["histogram"].items()}
    ax = axes[0]
    if hist:
        ax.bar(list(hist), list(hist.values()), color="#4c72b0")
    ax.set_yscale("log")
    ax.set_xlabel("patch degree (larger of u, v)")
    ax.set_ylabel("patches (log)")
    ax.set_title(f"degrees: max {rep['degree']['max']}, median {rep['degree']['median']:g}", fontsize=9)

    ax = axes[1]
    counts = np.array([f["patches"] for f in faces], dtype=float)
    if len(counts):
        bins = np.unique(np.round(np.logspace(0, np.log10(max(counts.max(), 1)) + 0.01, 30)))
        ax.hist(np.maximum(counts, 1), bins=np.append(bins, bins[-1] + 1), color="#55a868")
    ax.set_xscale("log")
    ax.set_xlabel("patches per input face (log)")
    ax.set_ylabel("faces")
    ax.set_title(f"{rep['faces_in']} faces -> {rep['patches_out']} patches", fontsize=9)

    ax = axes[2]
    key = "bound_after" if faces and "bound_after" in faces[0] else "bound"
    bound = np.array([f[key] for f in faces], dtype=float)
    sampled = np.array([f.get("deviation_after", f["deviation_sampled"]) for f in faces], dtype=float)
    allowed = np.array([f.get("bound_allowed", rep.get("tolerance", 0.0)) for f in faces], dtype=float)
    floor = max(rep["diagonal"] * 1e-16, 1e-300)
    if len(faces):
        order = np.argsort(-bound, kind="stable")
        x = np.arange(len(faces))
        ax.bar(x, np.maximum(bound[order], floor), color="#c44e52", width=1.0, label="bound per face")
        ax.plot(x, np.maximum(sampled[order], floor), ".", color="k", markersize=3, label="measured")
        ax.plot(x, allowed[order], "_", color="#4c72b0", markersize=6, label="allowed (I4)")
        ax.set_yscale("log")
        ax.legend(fontsize=7, frameon=False)
    ax.set_xlabel("input faces, largest bound first")
    ax.set_ylabel("deviation (mm, log)")
    ax.set_title("deviation per face", fontsize=9)
    fig.tight_layout()
    return _data_uri(fig, "svg")


# ------------------------------------------------------------------------------------ HTML pieces

CSS = """
body{font-family:sans-serif;margin:1.5em auto;max-width:1400px;color:#222;padding:0 1em}
h1{font-size:1.4em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ccc}
h3{font-size:1em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0}
td,th{border:1px solid #ccc;padding:2px 7px;text-align:right}
th{background:#f0f0f0}td.l,th.l{text-align:left}
figure{margin:.6em 0}img{max-width:100%}figcaption{font-size:.8em;color:#555}
.bad{color:#b00;font-weight:bold}.ok{color:#070}
"""


def _e(x) -> str:
    return html.escape(str(x))


def _num(x) -> str:
    if x is None:
        return "-"
    if isinstance(x, bool):
        return "yes" if x else "NO"
    if isinstance(x, float):
        return f"{x:.4g}"
    return _e(x)


def settings_rows(settings: dict) -> list[tuple[str, str]]:
    """Command-line settings as shown: lists joined, flags as yes/no, unset as '-'."""
    def show(v):
        if isinstance(v, bool):
            return "yes" if v else "no"
        if isinstance(v, list | tuple):
            return ", ".join(map(str, v))
        return "-" if v is None else v
    return [(k, show(v)) for k, v in settings.items()]


def kv_table(rows: list[tuple[str, object]]) -> str:
    body = "".join(f'<tr><th class="l">{_e(k)}</th><td class="l">{_num(v)}</td></tr>' for k, v in rows)
    return f"<table>{body}</table>"


def worst_edges_table(edge_gaps: list[dict], rows: int = WORST_ROWS) -> str:
    """The worst edges with the location (x, y, z) of their worst sample; numbers match the markers."""
    if not edge_gaps:
        return "<p>No edges measured.</p>"
    head = ("<tr><th>#</th><th>edge</th><th>faces</th><th>gap</th><th>C-S(pc)</th><th>S1-S2</th>"
            "<th>tolerance</th><th>gap / tol.</th><th>x</th><th>y</th><th>z</th></tr>")
    body = []
    for i, g in enumerate(edge_gaps[:rows]):
        ratio = g["gap"] / g["tolerance"] if g.get("tolerance") else None
        cls = ' class="bad"' if ratio is not None and ratio > 1 else ""
        x, y, z = g["where"]
        body.append(
            f"<tr><td>{i + 1}</td><td>{g['edge']}</td><td>{_e(','.join(map(str, g['faces'])) or '-')}</td>"
            f"<td{cls}>{g['gap']:.3g}</td><td>{g['curve_to_face']:.3g}</td><td>{g['face_to_face']:.3g}</td>"
            f"<td>{g['tolerance']:.3g}</td><td>{'-' if ratio is None else f'{ratio:.4g}'}</td>"
            f"<td>{x:.6g}</td><td>{y:.6g}</td><td>{z:.6g}</td></tr>")
    more = f"<p>{len(edge_gaps) - rows} more edges not listed.</p>" if len(edge_gaps) > rows else ""
    return f"<table>{head}{''.join(body)}</table>{more}"


def _page(title: str, body: str) -> str:
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{_e(title)}</title>'
            f"<style>{CSS}</style></head><body><h1>{_e(title)}</h1>{body}</body></html>\n")


def _gap_values(edge_gaps: list[dict]) -> np.ndarray:
    return np.array([g["gap"] for g in edge_gaps], dtype=float)


def _picture(scene: Scene, title: str, norm_range, per_face: bool, what: str) -> str:
    uri, notes = render(scene, title, norm_range, per_face)
    caption = what + (" " + "; ".join(notes) + "." if notes else "")
    return _figure(uri, caption, title)


EDGE_CAPTION = ("Edges coloured by their gap (log colour scale, bar on the right); numbered red circles "
                "are the worst samples of the edges numbered alike in the table.")


def report_section(rep: dict, scene: Scene | None, settings: dict) -> str:
    """One model of ``watertight report``: gap histogram, worst edges, picture, summary."""
    g = rep["gap"]
    gaps = _gap_values(rep["edge_gaps"])
    marks = [("largest edge tolerance", g["max_edge_tolerance"], "#dd8452")]
    parts = [f"<h2>{_e(rep['file'])}</h2>",
             kv_table([("format", rep["format"].upper()), ("units in file", rep["units_in_file"]),
                       ("faces", rep["faces"]), ("trimmed faces", rep["trimmed_faces"]),
                       ("surface types", ", ".join(f"{k} {v}" for k, v in rep["surface_types"].items())),
                       ("edges", rep["edges"]), ("free edges", rep["free_edges"]),
                       ("non-manifold edges", rep["nonmanifold_edges"]), ("solids", rep["solids"]),
                       ("shells", rep["shells"]), ("diagonal (mm)", rep["diagonal"]),
                       ("max gap (mm)", g["max"]), ("max gap / diagonal", g["max_relative"]),
                       ("median gap (mm)", g["median"]),
                       ("edges over their tolerance", g["edges_over_tolerance"])]),
             "<h3>Gap distribution</h3>",
             _figure(gap_histogram([("input", gaps, "#dd8452")], marks),
                     "Per edge: the larger of C vs S(pc) and S1(pc1) vs S2(pc2) over "
                     f"{g['samples_per_edge']} equal steps and "
                     f"{g.get('samples_per_knot_span', 0)} samples in every knot span.", "gap histogram"),
             "<h3>Worst edges</h3>", worst_edges_table(rep["edge_gaps"])]
    if scene is not None:
        parts += ["<h3>The model</h3>",
                  _picture(scene, "input model", gap_norm(gaps), False, EDGE_CAPTION)]
    parts += ["<h3>Settings and times</h3>",
              kv_table(settings_rows(settings)
                       + [(f"time {k} (s)", v) for k, v in rep["timing_s"].items()])]
    return "".join(parts)


def report_page(items: list[tuple[dict, Scene | None]], errors: list[str], settings: dict,
                build_seconds: float = 0.0) -> str:
    body = [f'<p class="bad">{_e(e)}</p>' for e in errors]
    t = time.perf_counter()
    for rep, scene in items:
        body.append(report_section(rep, scene, settings))
    body.append(f"<p>Page built in {build_seconds + time.perf_counter() - t:.1f} s by "
                f"{_e(items[0][0]['tool']) if items else 'watertight'}.</p>")
    return _page("watertight report", "".join(body))


def convert_page(rep: dict, before: Scene | None, after: Scene | None, settings: dict,
                 marks: list[tuple[str, float, str]], build_seconds: float = 0.0) -> str:
    """The page of one ``watertight convert`` run."""
    t = time.perf_counter()
    b, a = rep.get("before") or {}, rep.get("after") or {}
    inv = rep.get("invariants", {})
    gb = _gap_values(b.get("edge_gaps", []))
    ga = _gap_values(a.get("edge_gaps", [])) if "edge_gaps" in a else None
    norm_range = gap_norm(gb, ga)
    inv_html = ", ".join(f'{_e(k)} <span class="{"ok" if v else "bad"}">{"ok" if v else "FAILED"}</span>'
                         for k, v in inv.items())
    parts = [
        f"<p>{_e(rep['file'])} &rarr; {_e(rep['output'] or '(not written)')}</p>",
        f"<p>Invariants: {inv_html or '-'}</p>",
        "<h2>Summary</h2>",
        "<table><tr><th></th><th>before</th><th>after</th></tr>"
        + "".join(f'<tr><th class="l">{_e(k)}</th><td>{_num(x)}</td><td>{_num(y)}</td></tr>' for k, x, y in [
            ("faces", rep["faces_in"], a.get("faces", rep["patches_out"])),
            ("max gap (mm)", b.get("gap_max"), a.get("gap_max")),
            ("free edges", b.get("free_edges"), a.get("free_edges", a.get("free_edges_after_join"))),
            ("solids", b.get("solids"), a.get("solids")),
            ("shells", b.get("shells"), a.get("shells")),
            ("volume", b.get("volume"), a.get("volume")),
        ]) + "</table>",
        kv_table([("patches out", rep["patches_out"]), ("degree max / median",
                                                       f"{rep['degree']['max']} / {rep['degree']['median']}"),
                  ("stage", rep["stage"]), ("T-junctions", rep.get("t_junctions")),
                  ("deviation after, measured max (mm; I4)", rep.get("deviation_after_max")),
                  ("deviation bound max (mm)", rep.get("bound_after_max", rep["bound_max"])),
                  ("stage 1 sampled deviation max (mm)", rep["deviation_max_sampled"]),
                  ("volume change (relative)", a.get("volume_change_rel")), ("valid", a.get("valid")),
                  ("tessellation of the read-back (kernel mesh, welded)",
                   describe(a["tessellation"], b.get("free_edges") == 0) if a.get("tessellation") else None),
                  ("shared curves", ", ".join(f"{k} {v}" for k, v in rep.get("shared_curves", {}).items())),
                  ("problems", len(rep.get("problems", [])))]),
        "<h2>Gap distribution</h2>",
    ]
    series = [("before", gb, "#dd8452")]
    if ga is not None:
        series.append(("after (read back)", ga, "#4c72b0"))
    caption = "Per edge: the larger of C vs S(pc) and S1(pc1) vs S2(pc2)."
    if ga is None:
        caption += (" No gaps after: the written file was not read back (--fast, or --stage untrim, "
                    "whose patches share no edges).")
    parts.append(_figure(gap_histogram(series, marks), caption, "gap histogram before and after"))
    parts += ["<h2>Worst edges</h2><h3>Before</h3>", worst_edges_table(b.get("edge_gaps", []))]
    if ga is not None:
        parts += ["<h3>After (read back)</h3>", worst_edges_table(a["edge_gaps"])]
    parts.append("<h2>The model before and after</h2>")
    if before is not None:
        parts.append(_picture(before, "before: input faces", norm_range, True,
                              "Input faces in one colour each. " + EDGE_CAPTION))
    if after is not None:
        parts.append(_picture(after, "after: Bezier patches", norm_range, True,
                              "Patches coloured by their source face (same colours as before); thin dark "
                              "lines are the patch boundaries. " + EDGE_CAPTION))
    parts += ["<h2>Degrees, patches and deviation</h2>",
              _figure(distributions(rep), "Left: patches by degree. Middle: patches per input face. "
                      "Right: per input face the deviation bound (stage 1 plus substitution), the sampled "
                      "deviation and the allowed bound of invariant I4.", "distributions")]
    problems = rep.get("problems", [])
    if problems:
        items = "".join(f"<li>{_e(p)}</li>" for p in problems[:50])
        parts.append(f"<h3>Problems ({len(problems)})</h3><ul>{items}</ul>")
    parts += ["<h2>Settings and times</h2>",
              kv_table(settings_rows(settings)
                       + [("tolerance used by stage 1 (mm)", rep["tolerance"]),
                          ("diagonal (mm)", rep["diagonal"])]
                       + [(f"time {k} (s)", v) for k, v in rep["timings"].items()])]
    seconds = build_seconds + time.perf_counter() - t
    parts.append(f"<p>Page built in {seconds:.1f} s by {_e(rep['tool'])}.</p>")
    return _page(f"watertight convert: {Path(rep['file']).name}", "".join(parts))


# ------------------------------------------------------------------------------------ writing


def write_html(path: str | Path, text: str) -> None:
    """Write atomically: a temporary file beside the target, then ``os.replace``."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(path, f"folder {folder} does not exist")
    if path.is_dir():
        raise OutputError(path, "is a folder")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".html.tmp", dir=folder)
    except OSError as exc:
        raise OutputError(path, f"cannot write ({exc.strerror})") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
