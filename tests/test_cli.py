"""CLI behaviour: exit codes, one-line errors, --json, --help."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from click.testing import CliRunner

from watertight_cli.cli import EXIT_FAILED, EXIT_GATE, EXIT_OK, EXIT_USAGE, main

from .conftest import FIXTURES, fixture_path


def run(*args):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def one_line_error(result, name: str):
    assert "Traceback" not in result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("watertight: error:")]
    assert len(errors) == 1, result.output
    assert name in errors[0]
    return errors[0]


@pytest.mark.parametrize("name, reason", [
    ("empty.step", "empty file"),
    ("garbage.step", "not a STEP file"),
    ("truncated.step", "truncated STEP file"),
    ("unknown.xyz", "unknown file type"),
])
def test_bad_input_one_line(name, reason):
    path = fixture_path(f"broken/{name}")
    result = run("report", str(path))
    assert result.exit_code == EXIT_FAILED
    assert reason in one_line_error(result, name)


def test_missing_file(tmp_path):
    result = run("report", str(tmp_path / "nope.step"))
    assert result.exit_code == EXIT_FAILED
    assert "no such file" in one_line_error(result, "nope.step")


def test_folder_is_not_a_model(tmp_path):
    d = tmp_path / "dir.step"
    d.mkdir()
    result = run("report", str(d))
    assert result.exit_code in (EXIT_FAILED, EXIT_USAGE)
    assert "Traceback" not in result.output


def test_garbage_iges(tmp_path):
    bad = tmp_path / "bad.igs"
    bad.write_text("hello\n")
    result = run("report", str(bad))
    assert result.exit_code == EXIT_FAILED
    assert "not an IGES file" in one_line_error(result, "bad.igs")


def test_truncated_iges(tmp_path):
    src = fixture_path("loft_minus_cylinder.igs").read_bytes()
    bad = tmp_path / "cut.igs"
    bad.write_bytes(src[: len(src) // 2])
    result = run("report", str(bad))
    assert result.exit_code == EXIT_FAILED
    assert "truncated IGES" in one_line_error(result, "cut.igs")


def test_report_json_schema():
    result = CliRunner().invoke(main, ["report", "--json", "-q", str(fixture_path("open_sheet.step"))])
    assert result.exit_code == EXIT_OK, result.output
    doc = json.loads(result.stdout)
    assert doc["schema_version"] == 1
    for key in ("faces", "surface_types", "trimmed_faces", "edges", "free_edges", "nonmanifold_edges",
                "solids", "shells", "diagonal", "gap", "edge_gaps", "sewing", "timing_s"):
        assert key in doc
    assert doc["free_edges"] == 6 and doc["solids"] == 0
    gaps = [e["gap"] for e in doc["edge_gaps"]]
    assert gaps == sorted(gaps, reverse=True)  # worst first


def test_json_stdout_is_clean_with_several_files():
    files = [str(fixture_path("sphere.step")), str(FIXTURES / "broken" / "empty.step")]
    result = CliRunner().invoke(main, ["report", "--json", *files])
    assert result.exit_code == EXIT_FAILED
    doc = json.loads(result.stdout)
    assert [("error" in f) for f in doc["files"]] == [False, True]


def test_gate_exit_code():
    result = run("report", "-q", "--max-gap", "1e-30", str(fixture_path("loft_minus_cylinder.step")))
    assert result.exit_code == EXIT_GATE
    assert "exceeds --max-gap" in result.output


def test_usage_error_exit_code():
    result = CliRunner().invoke(main, ["report", "--samples", "1", "x.step"])
    assert result.exit_code == EXIT_USAGE


def test_every_command_has_help():
    assert run("--help").exit_code == 0
    for name, cmd in main.commands.items():
        result = run(name, "--help")
        assert result.exit_code == 0
        assert cmd.help and len(cmd.help) > 40, name
        assert "Exit codes" in result.output


def test_help_does_not_import_the_kernel():
    code = ("import sys; from watertight_cli.cli import main; "
            "assert not any(m.startswith('OCP') for m in sys.modules), 'OCP imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_kernel_failure_names_the_file(monkeypatch):
    from watertight_cli.errors import KernelError
    from watertight_cli.occ import extract

    def fail(*a, **k):
        raise KernelError("cannot convert a Geom_OffsetSurface to B-spline")

    monkeypatch.setattr(extract, "surface_bspline", fail)
    path = fixture_path("sphere.step")
    result = run("report", str(path))
    assert result.exit_code == EXIT_FAILED
    assert "cannot convert" in one_line_error(result, "sphere.step")


# ------------------------------------------------------------------------------ convert (stage 1)


def test_convert_untrim_writes_bezier_faces(tmp_path):
    out = tmp_path / "sphere_out.step"
    result = run("convert", "--stage", "untrim", "--json", "-q", str(fixture_path("sphere.step")), str(out))
    assert result.exit_code == EXIT_OK, result.output
    rep = json.loads(result.stdout)
    assert rep["stage"] == "untrim" and rep["verified"] is True
    assert rep["faces_in"] == 1 and rep["patches_out"] == 8
    assert rep["degree"]["max"] <= 25 and rep["folded_patches"] == 0 and rep["thin_patches"] == 0
    assert rep["bound_max"] <= 1e-9 * rep["diagonal"]
    # read back with the kernel: every face is an untrimmed Bezier patch
    from OCP.BRep import BRep_Tool
    from OCP.Geom import Geom_BezierSurface
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopoDS import TopoDS

    from watertight_cli.occ.extract import indexed
    from watertight_cli.occ.io import read_shape

    shape = read_shape(out).shape
    fmap = indexed(shape, TopAbs_FACE)
    assert fmap.Extent() == 8
    for i in range(1, fmap.Extent() + 1):
        surf = BRep_Tool.Surface_s(TopoDS.Face_s(fmap.FindKey(i)))
        # STEP has no Bezier entity: a Bezier patch comes back as a one-span B-spline
        assert isinstance(surf, Geom_BezierSurface) or (surf.NbUKnots() == 2 and surf.NbVKnots() == 2)


def test_convert_is_deterministic(tmp_path):
    a, b = tmp_path / "a" / "t.step", tmp_path / "b" / "t.step"
    for out in (a, b):
        out.parent.mkdir()
        result = run("convert", "--stage", "untrim", "-q", str(fixture_path("torus.step")), str(out))
        assert result.exit_code == 0
    assert a.read_bytes() == b.read_bytes()  # I6: same input and options, same bytes


def test_convert_full_writes_a_watertight_solid(tmp_path):
    out = tmp_path / "o.step"
    result = run("convert", "--json", "-q", str(fixture_path("two_solids.step")), str(out))
    assert result.exit_code == EXIT_OK, result.output
    rep = json.loads(result.stdout)
    assert rep["stage"] == "full" and rep["ok"] is True
    assert rep["invariants"] == {"I1": True, "I2": True, "I3": True, "I4": True, "valid": True}
    assert rep["after"]["solids"] == rep["before"]["solids"] == 2
    assert rep["after"]["free_edges"] == 0
    assert rep["after"]["gap_max"] <= 1e-12 * rep["diagonal"]
    assert rep["after"]["untrimmed_bezier_faces"] == rep["patches_out"]
    assert set(rep["shared_curves"]) <= {"3d curve", "3d curve, polynomial fit", "pole"}


def test_convert_gates_exit_3_and_keep_the_file(tmp_path):
    out = tmp_path / "o.step"
    result = run("convert", "-q", "--max-deviation", "1e-30", str(fixture_path("sphere.step")), str(out))
    assert result.exit_code == EXIT_GATE
    assert "--max-deviation" in one_line_error(result, "sphere.step")
    assert out.exists()


def test_convert_fast_skips_the_read_back(tmp_path):
    out = tmp_path / "o.step"
    result = run("convert", "--json", "-q", "--fast", str(fixture_path("sphere.step")), str(out))
    assert result.exit_code == EXIT_OK, result.output
    rep = json.loads(result.stdout)
    assert "read_back" not in rep["after"] and "I2" not in rep["invariants"]


def test_convert_bad_input_leaves_no_output(tmp_path):
    out = tmp_path / "o.step"
    result = run("convert", "--stage", "untrim", str(fixture_path("broken/garbage.step")), str(out))
    assert result.exit_code == EXIT_FAILED
    one_line_error(result, "garbage.step")
    assert not out.exists() and not list(tmp_path.iterdir())


def test_convert_json_error_document(tmp_path):
    result = run("convert", "--stage", "untrim", "--json", "-q", str(tmp_path / "nope.step"),
                 str(tmp_path / "o.step"))
    assert result.exit_code == EXIT_FAILED
    doc = json.loads(result.stdout)
    assert "nope.step" in doc["error"]


def test_convert_no_overwrite(tmp_path):
    out = tmp_path / "o.step"
    out.write_text("keep me")
    result = run("convert", "--stage", "untrim", "--no-overwrite", str(fixture_path("sphere.step")), str(out))
    assert result.exit_code == EXIT_FAILED
    assert out.read_text() == "keep me"


def test_convert_max_degree_option_is_respected(tmp_path):
    out = tmp_path / "o.step"
    result = run("convert", "--stage", "untrim", "--json", "-q", "--max-degree", "20",
                 str(fixture_path("loft_minus_cylinder.step")), str(out))
    assert result.exit_code == EXIT_OK, result.output
    rep = json.loads(result.stdout)
    assert rep["degree"]["max"] <= 20 and rep["verified"]
    assert rep["bound_max"] <= 1e-6 * rep["diagonal"] * 1.01


def test_convert_help_explains_stages():
    result = run("convert", "--help")
    assert result.exit_code == 0
    for word in ("--stage", "untrim", "--max-degree", "--tolerance", "atomically", "--fast", "--max-gap",
                 "--max-deviation", "shared curve"):
        assert word in result.output


def test_json_reports_take_numpy_numbers():
    """A report holding numpy scalars (np.bool_, np.int64 sums) still prints as JSON: no traceback."""
    import numpy as np

    from watertight_cli.cli import _jsonable

    doc = {"a": np.bool_(True), "n": np.int64(3), "x": np.float64(0.5), "v": np.arange(2)}
    assert json.loads(json.dumps(doc, default=_jsonable)) == {"a": True, "n": 3, "x": 0.5, "v": [0, 1]}


def test_written_file_gets_the_usual_permissions(tmp_path):
    """The atomic write goes through a 0600 temporary file; the result follows the umask."""
    import os

    out = tmp_path / "s.step"
    result = run("convert", "--stage", "untrim", "-q", str(fixture_path("sphere.step")), str(out))
    assert result.exit_code == 0
    mask = os.umask(0)
    os.umask(mask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~mask


def test_max_aspect_splits_slender_patches_sides(tmp_path):
    """open_sheet's stage 1 leaves strips more than 100 times longer than wide: by default their
    long sides are split into shorter edges (the same patches, more vertices, every invariant
    kept); --max-aspect inf leaves them as they are."""
    reps = {}
    for opt in ("100", "inf"):
        out = tmp_path / f"sheet_{opt}.step"
        result = run("convert", "--max-aspect", opt, "--json", "-q", str(fixture_path("open_sheet.step")),
                     str(out))
        assert result.exit_code == EXIT_OK, result.output
        reps[opt] = json.loads(result.stdout)
        assert reps[opt]["ok"] and all(reps[opt]["invariants"].values())
    split, whole = reps["100"]["after"], reps["inf"]["after"]
    assert whole["slender_patches_split"] == 0 and split["slender_patches_split"] > 0
    assert whole["clearance_split_vertices"] == 0
    assert split["slender_split_vertices"] > split["slender_patches_split"]
    assert reps["100"]["patches_out"] == reps["inf"]["patches_out"]
    assert split["t_vertices"] == whole["t_vertices"]
    assert reps["100"]["deviation_after_max"] == reps["inf"]["deviation_after_max"]
    assert run("convert", "--max-aspect", "1", "x.step", "y.step").exit_code == EXIT_USAGE
