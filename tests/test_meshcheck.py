"""The tessellation check (``watertight_cli.meshcheck``): welding and edge counts."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from watertight_cli.meshcheck import tessellation_check, weld

_CORNERS = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
# the cube's six sides as corner loops (indices into _CORNERS: bit 2 x, bit 1 y, bit 0 z)
_SIDES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def cube_faces(rng=None, jitter=0.0):
    """A unit cube as the kernel triangulates a B-rep: per face its own copy of its nodes (a 3 x 3
    grid: boundary nodes shared with the neighbours only by position), eight triangles each."""
    out = []
    for a, b, c, d in _SIDES:
        A, B, C, D = (_CORNERS[k] for k in (a, b, c, d))
        g = np.linspace(0.0, 1.0, 3)
        pts = np.array([(1 - s) * (1 - t) * A + s * (1 - t) * B + s * t * C + (1 - s) * t * D
                        for t in g for s in g])
        if rng is not None:
            pts = pts + rng.uniform(-jitter, jitter, pts.shape)
        tris = []
        for j in range(2):
            for i in range(2):
                k = 3 * j + i
                tris += [(k, k + 1, k + 4), (k, k + 4, k + 3)]
        out.append((pts, np.array(tris)))
    return out


def test_closed_cube_is_watertight():
    c = tessellation_check(cube_faces(), 1e-9)
    assert c["watertight"] and c["triangles"] == 48
    assert c["free_edges"] == c["nonmanifold_edges"] == c["degenerate_triangles"] == 0


def test_a_missing_triangle_leaves_three_free_edges():
    faces = cube_faces()
    pts, tris = faces[2]
    faces[2] = (pts, tris[1:])
    c = tessellation_check(faces, 1e-9)
    assert not c["watertight"] and c["free_edges"] == 3 and c["nonmanifold_edges"] == 0
    # the hole's three edges: two inside face 2, one on its side with face 4 (that one's triangle)
    assert c["faces_with_free_edges"] == [2, 4]


def test_an_empty_face_is_not_watertight():
    faces = cube_faces() + [(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))]
    c = tessellation_check(faces, 1e-9)
    assert c["empty_faces"] == 1 and not c["watertight"]


def test_nodes_farther_apart_than_the_weld_stay_apart():
    rng = np.random.default_rng(1)
    c = tessellation_check(cube_faces(rng, 1e-3), 1e-6)
    assert not c["watertight"] and c["free_edges"] > 0


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(1e-9, 1e-3))
def test_jitter_below_a_third_of_the_weld_keeps_the_cube_watertight(seed, distance):
    """Every copy of a node moves by less than distance / 3 (per coordinate, so by less than
    distance / sqrt(3) in space): any two copies are within the weld, wherever they fall."""
    rng = np.random.default_rng(seed)
    c = tessellation_check(cube_faces(rng, distance / 3.0), distance)
    assert c["watertight"], c


def test_a_face_narrower_than_the_weld_is_reported():
    """A strip eps wide between two faces: welded, its two triangles collapse to segments and the
    edge they lie on gets more than two triangles."""
    eps = 1e-7
    left = (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, -1.0, 0.0]]), np.array([[0, 1, 2]]))
    right = (np.array([[0.0, eps, 0.0], [1.0, eps, 0.0], [0.5, 1.0, 0.0]]), np.array([[1, 0, 2]]))
    strip = (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, eps, 0.0], [0.0, eps, 0.0]]),
             np.array([[0, 1, 2], [0, 2, 3]]))
    c = tessellation_check([left, right, strip], 1e-6)
    assert c["degenerate_triangles"] == 2 and c["faces_with_degenerate"] == [2]
    assert c["nonmanifold_edges"] == 1 and not c["watertight"]
    # a weld below the strip's width keeps its triangles: six free edges around the three faces
    # and none with more than two triangles
    c = tessellation_check([left, right, strip], 1e-8)
    assert c["degenerate_triangles"] == 0 and c["nonmanifold_edges"] == 0 and c["free_edges"] == 6


def test_weld_joins_across_grid_lines_and_along_chains():
    """Rounding to a grid would part 0.49999999 and 0.50000001; a chain of close points is one
    node even where its ends are farther apart than the weld."""
    pts = np.array([[0.49999999, 0.0, 0.0], [0.50000001, 0.0, 0.0], [2.0, 0.0, 0.0],
                    [2.0 + 0.8e-6, 0.0, 0.0], [2.0 + 1.6e-6, 0.0, 0.0]])
    node = weld(pts, 1e-6)
    assert list(node) == [0, 0, 1, 1, 1]
    assert len(weld(np.zeros((0, 3)), 1.0)) == 0


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_counts_do_not_depend_on_face_order(seed):
    rng = np.random.default_rng(seed)
    faces = cube_faces(rng, 1e-4)  # some nodes weld at 1e-4, some do not
    order = rng.permutation(len(faces))
    a = tessellation_check(faces, 1e-4)
    b = tessellation_check([faces[i] for i in order], 1e-4)
    for k in ("triangles", "free_edges", "nonmanifold_edges", "degenerate_triangles", "watertight"):
        assert a[k] == b[k]
    # watertight is trimesh's own test on the welded mesh (the check itself does not import it)
    import trimesh

    P = np.concatenate([p for p, _ in faces])
    base = np.cumsum([0] + [len(p) for p, _ in faces])
    node = weld(P, 1e-4)
    T = np.concatenate([node[t + base[i]] for i, (_, t) in enumerate(faces)])
    mesh = trimesh.Trimesh(np.zeros((node.max() + 1, 3)), T, process=False)
    assert a["watertight"] == mesh.is_watertight
    # and the edge counts are trimesh's, from its own edges_sorted
    counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)[1]
    assert (a["free_edges"], a["nonmanifold_edges"]) == (int((counts == 1).sum()), int((counts > 2).sum()))


def test_a_mesher_failure_is_reported_and_the_conversion_goes_on(tmp_path, monkeypatch):
    """The tessellation is a figure, not a gate: a kernel exception while meshing the read-back
    leaves the reason in the report, and the file, the invariants and the exit status stand."""
    from watertight_cli.convert import convert_file
    from watertight_cli.occ import mesh
    from watertight_cli.stage2 import format_full_table
    from watertight_cli.tolerances import Tolerances

    from .conftest import fixture_path

    def broken(shape, deflection_rel=2e-3, angle=0.5, copy=True):
        raise RuntimeError("mesher gave up\nsecond line")

    monkeypatch.setattr(mesh, "triangulate", broken)
    out = tmp_path / "o.step"
    rep = convert_file(str(fixture_path("two_solids.step")), str(out), Tolerances())
    assert out.exists() and rep["ok"]
    assert rep["after"]["tessellation"] == {"error": "RuntimeError: mesher gave up"}
    assert "tessellation: not measured (RuntimeError: mesher gave up)" in format_full_table(rep)


def test_touching_shells_are_checked_each_on_its_own():
    """Two cubes that share a side: one mesh of both has four triangles on each edge of the shared
    side; shell by shell, each cube is closed."""
    a = cube_faces()
    b = [(p + np.array([1.0, 0.0, 0.0]), t) for p, t in cube_faces()]
    whole = tessellation_check(a + b, 1e-9)
    assert not whole["watertight"] and whole["nonmanifold_edges"] > 0
    each = tessellation_check(a + b, 1e-9, [list(range(6)), list(range(6, 12))])
    assert each["watertight"] and each["shells"] == 2 and each["triangles"] == 96
    assert each["nonmanifold_edges"] == each["free_edges"] == 0
    # faces in no shell are checked as one more: half a cube is open
    rest = tessellation_check(a + b[:3], 1e-9, [list(range(6))])
    assert rest["shells"] == 2 and not rest["watertight"] and rest["free_edges"] > 0
    assert set(rest["faces_with_free_edges"]) <= {6, 7, 8}
