"""Assembly structure and names (I3): a STEP file's tree is read, each part converted once, and the
output written with the same tree, placements and names; a solid with a void stays one solid."""

from __future__ import annotations

import hashlib

import pytest

from watertight_cli.tolerances import Tolerances

from .conftest import fixture_path


def _plain_read(path):
    """The file as OCCT's plain STEP reader sees it (no XCAF, none of the project's reading code)."""
    from OCP.STEPControl import STEPControl_Reader

    from watertight_cli.occ.io import quiet

    reader = STEPControl_Reader()
    with quiet():
        reader.ReadFile(str(path))
        reader.TransferRoots()
    return reader.OneShape()


def _write_twice(st, folder) -> list[str]:
    """The input's parts written with the tree ``st`` into folder/a and folder/b: the files' digests."""
    from watertight_cli.occ.io import write_shape
    from watertight_cli.occ.structure import Output, bodies

    digests = []
    for sub in ("a", "b"):
        (folder / sub).mkdir()
        write_shape(Output(st, [[b for b, _ in bodies(p)] for p in st.parts]), folder / sub / "x.step")
        digests.append(hashlib.sha256((folder / sub / "x.step").read_bytes()).hexdigest())
    return digests


def _count(shape, kind) -> int:
    from watertight_cli.occ.extract import count

    return count(shape, kind)


def test_the_tree_is_read_and_each_part_is_converted_once():
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID

    from watertight_cli.occ.io import read_shape

    read = read_shape(fixture_path("assembly.step"))
    st = read.structure
    assert st.counts() == {"parts": 2, "assemblies": 2, "instances": 5, "named_bodies": 1}
    tree = st.describe()
    assert [r["name"] for r in tree] == ["rig"]
    assert [c["name"] for c in tree[0]["components"]] == ["left", "right", "core"]
    pair = tree[0]["components"][0]["node"]
    assert pair["name"] == "pair" and [c["name"] for c in pair["components"]] == ["lower", "upper"]
    assert pair["components"][0]["node"]["bodies"] == [{"kind": "solid", "name": "plate body"}]
    # the plate is placed four times in the file, and the pipeline gets it once
    placed = _plain_read(fixture_path("assembly.step"))
    assert _count(placed, TopAbs_SOLID) == 5
    assert _count(read.shape, TopAbs_SOLID) == 2
    assert 2 * _count(read.shape, TopAbs_FACE) < _count(placed, TopAbs_FACE)


def test_same_tree_compares_names_and_placements():
    from watertight_cli.occ.structure import same_tree

    def tree(x: float) -> list:
        part = {"name": "plate", "bodies": [{"kind": "solid", "name": "b"}]}
        return [{"name": "rig", "components": [{"name": "left", "placement": [[1.0, 0.0, 0.0, x]] * 3,
                                                "node": part}]}]

    a, b = tree(5.0), tree(5.0 + 1e-12)
    assert same_tree(a, b)
    b[0]["components"][0]["node"]["bodies"][0]["name"] = None
    assert not same_tree(a, b)
    b[0]["components"][0]["node"]["bodies"][0]["name"] = "b"
    b[0]["components"][0]["placement"] = [[1.0, 0.0, 0.0, 5.1]] * 3
    assert not same_tree(a, b)


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    from watertight_cli.convert import convert_file

    out = tmp_path_factory.mktemp("asm") / "rig.step"
    rep = convert_file(str(fixture_path("assembly.step")), str(out), Tolerances())
    return rep, out


def test_an_assembly_is_written_with_its_tree_names_and_void(converted):
    """The output has the input's assemblies, placements, product, instance and body names; every
    invariant holds; the hollow block (one solid, two shells) is one solid with its void: before,
    each shell of a solid became a solid of its own, and the void's a solid filling it."""
    from OCP.TopAbs import TopAbs_SHELL, TopAbs_SOLID

    from watertight_cli.occ.io import read_shape
    from watertight_cli.occ.structure import same_tree

    rep, out = converted
    assert rep["invariants"] == {"I1": True, "I2": True, "I3": True, "I4": True, "valid": True}
    assert rep["structure"]["written"] == "tree" and rep["after"]["structure_kept"] is True
    assert rep["after"]["solids"] == rep["before"]["solids"] == 2
    assert rep["after"]["volume_change_rel"] <= 1e-9
    assert same_tree(read_shape(out).structure.describe(), rep["structure"]["tree"])
    # the kernel's plain reader places the parts: five solids, one of them with a void
    placed = _plain_read(out)
    assert _count(placed, TopAbs_SOLID) == 5 and _count(placed, TopAbs_SHELL) == 6
    text = out.read_bytes()
    for name in (b"'rig'", b"'pair'", b"'plate'", b"'hollow'", b"'left'", b"'right'", b"'core'",
                 b"'upper'", b"'lower'", b"MANIFOLD_SOLID_BREP('plate body'"):
        assert name in text, name
    assert b"BREP_WITH_VOIDS" in text


def test_a_tree_is_written_the_same_twice(converted, tmp_path):
    """I6 for the XCAF writer: the same parts and tree give the same bytes."""
    from watertight_cli.occ.io import read_shape

    _, out = converted
    a, b = _write_twice(read_shape(out).structure, tmp_path)
    assert a == b


def test_iges_output_of_an_assembly_is_flat_and_says_so(tmp_path):
    from watertight_cli.convert import convert_file
    from watertight_cli.stage2 import format_full_table

    rep = convert_file(str(fixture_path("two_solids.step")), str(tmp_path / "o.igs"), Tolerances())
    assert rep["ok"]
    assert rep["structure"]["written"] == "flat" and "structure_kept" not in rep["after"]
    assert "written flat (IGES" in format_full_table(rep)


@pytest.mark.parametrize("names", [("Part 2", "Part 1"), ("", "")])
def test_names_are_written_as_read(tmp_path, names):
    """A name ending in a number is a name ("Part 2": the plain writer's counter suffix was once
    stripped from every product, which took gmsh__wing_fuselage's "Part 1" and "Part 2" to "Part"),
    and an unnamed node stays unnamed, in the same bytes each time (the writer names unnamed
    products with a per-process counter)."""
    from watertight_cli.occ.io import read_shape
    from watertight_cli.occ.structure import same_tree

    st = read_shape(fixture_path("assembly.step")).structure
    st.nodes[st.roots[0]].name, st.nodes[0].name = names  # the root and the first part
    a, b = _write_twice(st, tmp_path)
    assert a == b
    back = read_shape(tmp_path / "a" / "x.step").structure.describe()
    assert same_tree(back, st.describe())
    assert back[0]["name"] == names[0]


def test_stage_one_output_keeps_the_tree(tmp_path):
    """``--stage untrim`` writes one open shell per input body, each in its part of the input's tree
    (before: every part's patches in one shell, each part once, unplaced)."""
    from OCP.TopAbs import TopAbs_FACE

    from watertight_cli.convert import convert_file
    from watertight_cli.occ.io import read_shape

    out = tmp_path / "s1.step"
    rep = convert_file(str(fixture_path("assembly.step")), str(out), Tolerances(), stage="untrim")
    st = read_shape(out).structure
    assert {k: v for k, v in st.counts().items() if k != "named_bodies"} == {
        "parts": 2, "assemblies": 2, "instances": 5}
    # each part once in the tree's parts, four plates and one hollow block when placed
    parts = read_shape(out).shape
    assert _count(parts, TopAbs_FACE) == rep["faces_written"]
    assert _count(_plain_read(out), TopAbs_FACE) > 2 * rep["faces_written"]
