"""`watertight report` on real files agrees with the independent checker's published figures.

The corpus README lists, per file, the max gap and free-edge count measured by
``shared/tools/judge.py`` at equally spaced samples; measured at equal steps too, the report must
agree within a factor of 2 (or both be below 1e-9 x diagonal). The report's own figure adds
samples in every knot span and can only be larger. Skips when ../shared/corpus is missing.
"""

from __future__ import annotations

import pytest

from watertight_cli.inspect import inspect
from watertight_cli.report import input_report

from .conftest import corpus_files, corpus_path, corpus_table

TABLE = corpus_table()


@pytest.mark.parametrize("name", corpus_files() or ["(corpus missing)"])
def test_report_agrees_with_checker(name, tol):
    path = corpus_path(name)
    expected = TABLE.get(name)
    if expected is None:
        pytest.skip(f"{name} not in the corpus table")
    from watertight_cli.gaps import max_gap
    from watertight_cli.occ.extract import sample_tracks

    ins = inspect(str(path), tol)
    r = input_report(ins)
    ours = max_gap(sample_tracks(ins.shape, tol.gap_samples, per_span=0))  # equal steps only
    if r["sewing"] is not None:  # the report's figure includes the faces as read, before sewing
        from watertight_cli.occ.io import read_shape

        ours = max(ours, max_gap(sample_tracks(read_shape(str(path)).shape, tol.gap_samples, per_span=0)))
    theirs, diag = expected["max_gap"], r["diagonal"]
    assert r["gap"]["max"] >= ours
    assert r["faces"] == expected["faces"]
    assert abs(diag - expected["diag"]) <= 0.01 * expected["diag"]
    both_tiny = ours < 1e-9 * diag and theirs < 1e-9 * diag
    # the table rounds to 2 significant digits; allow for that on top of the factor of 2
    assert both_tiny or (theirs / 2.1 <= ours <= 2.1 * theirs), (ours, theirs)
    if r["sewing"] is None:
        assert r["free_edges"] == expected["free"]
    else:  # sewing can only recover adjacency
        assert r["free_edges"] <= expected["free"]
    # the arrays the pipeline works on describe the same boundaries as the kernel does
    kernel = {g.edge: g.gap for g in ins.gaps}
    worst = max(abs(g.gap - kernel[g.edge]) for g in ins.array_gaps)
    assert worst <= 1e-9 * diag, worst


@pytest.mark.slow
@pytest.mark.parametrize("name", corpus_files())
def test_corpus_file_untrims_and_verifies(name):
    """Stage 1 on every real file, as ``convert --stage untrim`` runs it (re-timed pcurves, half the
    tolerance first, the retries): the own verify step passes (deviation within the bounds,
    trimming sides on S(pcurve), areas, no folds). At the whole tolerance alone
    gmsh__wing_fuselage.step kept a folded cell in face 13. Slow: minutes per file on two cores."""
    from watertight_cli.convert import convert_file
    from watertight_cli.tolerances import Tolerances

    report = convert_file(str(corpus_path(name)), None, Tolerances(), "untrim")
    assert report["verified"]
    assert report["folded_patches"] == 0
    assert all(not f["problems"] for f in report["faces"])


@pytest.mark.slow
def test_untrim_output_reads_back_untrimmed(tmp_path):
    """``--stage untrim`` leaves out patches without area (a cell between coinciding sides): on
    gmsh__U_Joint_2.stp 56 of them were written, and the STEP reader rebuilt the pcurves of 4
    across the collapsed band, so those faces read back trimmed. Slow: several minutes (reading
    back an 88 MB file)."""
    from watertight_cli.convert import convert_file
    from watertight_cli.inspect import trimmed
    from watertight_cli.tolerances import Tolerances

    out = tmp_path / "uj.step"
    report = convert_file(str(corpus_path("gmsh__U_Joint_2.stp")), str(out), Tolerances(), "untrim")
    assert report["flat_patches_dropped"] > 0
    back = inspect(str(out), Tolerances(), array_gaps=False).model
    written = report["patches_out"] - report["flat_patches_dropped"]
    assert len(back.faces) == report["faces_written"] == written
    assert not [f.index for f in back.faces if trimmed(f)]


@pytest.mark.slow
def test_fusee_reads_back_with_every_face_untrimmed(tmp_path):
    """gmsh__917_fusee.stp, converted in full and read back: every face an untrimmed Bezier patch
    (I1). At a cusp stage 2 leaves a corner 1.7e-7 off a neighbour's side; with the file's
    uncertainty at OCCT's default 1e-7 the reader projected those pcurves again, 2.4e-8 outside
    [0, 1]^2, and one face of 17387 read back trimmed. Slow: about three minutes."""
    from watertight_cli.convert import convert_file
    from watertight_cli.tolerances import Tolerances

    name = "gmsh__917_fusee.stp"
    if name not in corpus_files():
        pytest.skip(f"{name} not in the corpus")
    report = convert_file(str(corpus_path(name)), str(tmp_path / "f.step"), Tolerances(), "full")
    after = report["after"]
    assert report["invariants"]["I1"]
    # 11030 faces since spare knots are dropped on reading (703835e); 17387 before 5f48509
    assert after["read_back"] and after["untrimmed_bezier_faces"] == after["faces"] > 10000
    assert after["free_edges"] == 0 and after["gap_max_relative"] <= 1e-9


@pytest.mark.slow
def test_occ22470_output_is_closed_without_the_topology(tmp_path):
    """occt__occ22470.igs converted in full: every point of every face's boundary lies within I2's
    line (1e-12 of the diagonal) of another face's boundary, measured without the topology
    (``boundary``). The independent checker leaves 2 of the same 480780 points unmatched: it
    measures each against the curve of the nearest of its own samples, and at two corners where
    the sides leave almost tangent (0.003 and 0.004 rad) that is a third face's. Slow: about a
    minute and a half."""
    from watertight_cli.boundary import boundary_gap
    from watertight_cli.convert import convert_file
    from watertight_cli.tolerances import Tolerances

    name = "occt__occ22470.igs"
    if name not in corpus_files():
        pytest.skip(f"{name} not in the corpus")
    keep: dict = {}
    report = convert_file(str(corpus_path(name)), str(tmp_path / "o.igs"), Tolerances(), "full", keep=keep)
    assert report["ok"]
    g = boundary_gap(keep["read_back"].model)
    assert g.samples > 400000
    assert g.unmatched == 0
    assert g.matched_max <= Tolerances().watertight_rel * report["diagonal"], (g.matched_max, g.where)
