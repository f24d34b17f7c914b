"""Mesh-level check of a tessellation (arrays in, a summary out; no kernel code).

What a mesher sees of the written model: the faces' triangles, with nodes closer than a weld
distance taken as one node. The mesh is watertight when every edge of it has exactly two
triangles. Two things break that on a model whose faces share their edges exactly (I2):

- a free mesh edge (one triangle): a hole, or an open boundary where the input is open;
- an edge with three or more triangles: welding joined nodes across a face narrower than the weld
  distance somewhere (a cusp where two of its sides run together, or a sliver), which leaves
  zero-area triangles and lays the face's triangles over its neighbours' edges.

The weld distance is the caller's (``Tolerances.sliver_rel`` of the diagonal in the read-back:
the narrowest cell stage 1 makes, below which two points are one).
"""

from __future__ import annotations

import numpy as np

__all__ = ["describe", "tessellation_check", "weld"]

_FIRST = 10  # faces listed by index in the summary


def weld(points: np.ndarray, distance: float) -> np.ndarray:
    """Index of each point's node: points joined by a chain of steps no longer than ``distance``
    are one node (numbered from 0 in the order of their first point). Unlike rounding to a grid,
    two points on either side of a grid line still join."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=float)
    n = len(points)
    if n == 0:
        return np.zeros(0, dtype=int)
    pairs = (cKDTree(points).query_pairs(distance, output_type="ndarray") if distance > 0
             else np.zeros((0, 2), dtype=int))
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    # renumber by first appearance, so that the numbering does not depend on scipy's
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[label]


def tessellation_check(faces: list[tuple[np.ndarray, np.ndarray]], distance: float,
                       shells: list[list[int]] | None = None) -> dict:
    """Weld the faces' triangles (per face: nodes (n, 3), triangles (m, 3) indices into them) at
    ``distance`` and count what breaks watertightness (see the module's text), shell by shell:
    ``shells`` lists each shell's face indices (None: all faces are one shell), and faces in no
    shell are one more. Solids that touch (an assembly's parts, a wing against its fuselage)
    share mesh edges between their shells, which says nothing about either shell, so each is
    welded and counted on its own and the counts are summed.

    Returns a dict: shells, triangles, empty_faces (faces with no triangle), free_edges (mesh
    edges of one triangle), nonmanifold_edges (three or more), degenerate_triangles (two corners
    welded into one node), faces_with_degenerate and faces_with_free_edges (the first few face
    indices), weld (the distance used), and watertight (for every shell, trimesh's definition:
    each mesh edge has exactly two triangles; and no face is empty)."""
    groups = [list(range(len(faces)))] if shells is None else [list(g) for g in shells if len(g)]
    if shells is not None:
        seen = {i for g in groups for i in g}
        rest = [i for i in range(len(faces)) if i not in seen]
        if rest:
            groups.append(rest)
    out = {"shells": len(groups), "triangles": 0, "empty_faces": 0, "free_edges": 0, "nonmanifold_edges": 0,
           "degenerate_triangles": 0, "faces_with_degenerate": [], "faces_with_free_edges": [],
           "weld": distance, "watertight": bool(groups)}
    for g in groups:
        one = _check_shell([faces[i] for i in g], np.asarray(g, dtype=int), distance)
        for k in ("triangles", "empty_faces", "free_edges", "nonmanifold_edges", "degenerate_triangles"):
            out[k] += one[k]
        for k in ("faces_with_degenerate", "faces_with_free_edges"):
            out[k] = sorted(set(out[k]) | set(one[k]))[:_FIRST]
        out["watertight"] = out["watertight"] and one["watertight"]
    return out


def _check_shell(faces: list[tuple[np.ndarray, np.ndarray]], index: np.ndarray, distance: float) -> dict:
    """``tessellation_check`` of one shell's faces; ``index`` maps them to the caller's numbers."""
    pts, tris, owner = [], [], []
    base = 0
    empty = 0
    for fi, (p, t) in enumerate(faces):
        if len(t) == 0:
            empty += 1
            continue
        pts.append(np.asarray(p, dtype=float))
        tris.append(np.asarray(t, dtype=int) + base)
        owner.append(np.full(len(t), index[fi]))
        base += len(p)
    out = {"triangles": 0, "empty_faces": empty, "free_edges": 0, "nonmanifold_edges": 0,
           "degenerate_triangles": 0, "faces_with_degenerate": [], "faces_with_free_edges": [],
           "watertight": False}
    if not tris:
        return out
    P = np.concatenate(pts)
    node = weld(P, distance)
    V = np.empty((int(node.max()) + 1, 3))
    V[node] = P  # a node stands where one of its points is
    T = node[np.concatenate(tris)]
    own = np.concatenate(owner)
    bad = (T[:, 0] == T[:, 1]) | (T[:, 1] == T[:, 2]) | (T[:, 2] == T[:, 0])
    # a welded-away triangle is a segment: its edges still count (twice over one pair), as a
    # mesher that keeps it would see them
    # each triangle's three edges in turn (edge k belongs to triangle k // 3), each as (low, high),
    # as trimesh's ``edges_sorted``: the arithmetic is one line, and importing trimesh for it cost
    # 0.1-0.2 s of every read-back (the tests hold the result against trimesh's ``is_watertight``)
    edges = np.sort(T[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    free_tri = np.unique(np.flatnonzero(counts[inverse.reshape(-1)] == 1) // 3)
    out.update({
        "triangles": int(len(T)),
        "free_edges": int((counts == 1).sum()),
        "nonmanifold_edges": int((counts > 2).sum()),
        "degenerate_triangles": int(bad.sum()),
        "faces_with_degenerate": [int(f) for f in np.unique(own[bad])[:_FIRST]],
        "faces_with_free_edges": [int(f) for f in np.unique(own[free_tri])[:_FIRST]],
        # trimesh's definition of watertight: every edge has exactly two triangles
        "watertight": bool(empty == 0 and np.all(counts == 2)),
    })
    return out


def describe(t: dict, closed: bool) -> str:
    """One line for a ``tessellation_check`` summary (the report's table and HTML page). ``closed``:
    the input had no free edges, so free mesh edges are faults, not its open boundary."""
    if "error" in t:
        return f"not measured ({t['error']})"
    faults = [f"{t[k]} {what}" for k, what in (
        ("free_edges", "free mesh edges" + ("" if closed else " (open input)")),
        ("nonmanifold_edges", "mesh edges with 3+ triangles"),
        ("degenerate_triangles", "triangles with two corners at one node"),
        ("empty_faces", "faces left untriangulated")) if t[k]]
    where = [f"{what} in faces {', '.join(map(str, listed))}{', ...' if len(listed) >= _FIRST else ''}"
             for what, listed, show in (("free mesh edges", t.get("faces_with_free_edges", []), closed),
                                        ("two corners at one node", t["faces_with_degenerate"], True))
             if listed and show]
    state = "watertight" if t["watertight"] else ("not watertight" if closed else "open")
    shells = f" in {t['shells']} shells" if t.get("shells", 1) > 1 else ""
    return (f"{state}, {t['triangles']} triangles{shells} welded at {t['weld']:.2g}"
            + (": " + ", ".join(faults) if faults else "") + (f" ({'; '.join(where)})" if where else ""))
