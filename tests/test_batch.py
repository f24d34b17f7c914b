"""Batch conversion (`watertight convert IN... -o OUTDIR`): bad files, crashing and hanging workers,
reports for CI, safety of inputs and outputs, Dask.

One batch run over a small folder (four fixtures, one in a subfolder, and three broken files) is
shared by several tests; the other runs convert one or two small fixtures each.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from click.testing import CliRunner

from watertight_cli.batch import plan, remove_temp_files
from watertight_cli.cli import EXIT_FAILED, EXIT_GATE, EXIT_OK, EXIT_USAGE, main
from watertight_cli.errors import UsageError

from .conftest import CORPUS, fixture_path

GOOD = {"sphere.step": "sphere.step", "torus.step": "torus.step", "open_sheet.step": "open_sheet.step",
        "sub/two_solids.step": "two_solids.step"}
BROKEN = {"empty.step": "empty file", "garbage.step": "not a STEP file",
          "truncated.step": "truncated STEP file"}


def run(*args, env=None):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False, env=env)


def error_lines(result) -> list[str]:
    assert "Traceback" not in result.output
    return [ln for ln in result.output.splitlines() if ln.startswith("watertight: error:")]


def digests(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def make_input(folder: Path, good=GOOD, broken=BROKEN) -> Path:
    for rel, name in good.items():
        (folder / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(fixture_path(name), folder / rel)
    for name in broken:
        shutil.copyfile(fixture_path(f"broken/{name}"), folder / name)
    return folder


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """One run: a folder of 4 fixtures (one in sub/) and 3 broken files, --jobs 2, every report."""
    root = tmp_path_factory.mktemp("batch")
    src = make_input(root / "in")
    before = digests(src)
    out = root / "out"
    result = run("convert", src, "-o", out, "--recursive", "--jobs", 2, "--report", root / "r.json",
                 "--junit", root / "j.xml", "--json")
    return {"root": root, "src": src, "out": out, "before": before, "result": result,
            "doc": json.loads(root.joinpath("r.json").read_text())}


def test_batch_exit_code_and_one_line_per_broken_file(batch):
    result = batch["result"]
    assert result.exit_code == EXIT_FAILED, result.output
    lines = error_lines(result)
    assert len(lines) == len(BROKEN), lines
    for name, reason in BROKEN.items():
        assert sum(name in ln and reason in ln for ln in lines) == 1, (name, lines)


def test_batch_writes_every_good_file_in_a_mirrored_tree(batch):
    out = batch["out"]
    written = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert written == sorted(GOOD)  # sub/two_solids.step mirrors in/sub/; nothing for broken files
    assert not [p for p in out.rglob(".*")]  # no temporary file left


def test_batch_inputs_are_untouched(batch):
    assert digests(batch["src"]) == batch["before"]


def test_batch_output_equals_the_one_file_form(batch, tmp_path):
    """A worker process writes the same bytes as `convert IN OUT` (I6)."""
    out = tmp_path / "torus.step"
    assert run("convert", "-q", batch["src"] / "torus.step", out).exit_code == EXIT_OK
    assert out.read_bytes() == (batch["out"] / "torus.step").read_bytes()


def test_batch_json_report(batch):
    doc = batch["doc"]
    assert json.loads(batch["result"].stdout) == doc  # --json prints the --report document
    assert doc["schema_version"] == 1
    files = {f["path"]: f for f in doc["files"]}
    assert set(files) == set(GOOD) | set(BROKEN)
    for rel in GOOD:
        f = files[rel]
        assert f["status"] in ("ok", "gate") and f["failure"] is None, f["reason"]
        assert f["faces"] >= 1 and f["patches"] >= f["faces"]
        assert f["gap_after"] is not None and f["report"]["output"].endswith(rel)
    for name, reason in BROKEN.items():
        assert files[name]["status"] == "failed" and files[name]["failure"] == "error"
        assert reason in files[name]["reason"] and files[name]["report"] is None
    t = doc["totals"]
    assert t["files"] == 7 and t["failed"] == 3 and t["ok"] + t["gate"] == 4
    assert t["faces"] == sum(files[r]["faces"] for r in GOOD)
    assert doc["options"]["jobs"] == 2 and doc["options"]["recursive"] is True
    assert all(files[r]["cpu_s"] > 0 for r in GOOD) and t["cpu_s"] > 0 and t["time_s"] > 0


def test_batch_junit_report(batch):
    root = ET.parse(batch["root"] / "j.xml").getroot()
    assert root.tag == "testsuites"
    suite = root.find("testsuite")
    cases = suite.findall("testcase")
    assert int(suite.get("tests")) == len(cases) == 7
    failed = {c.get("name"): c.find("failure") for c in cases if c.find("failure") is not None}
    gates = {f["path"] for f in batch["doc"]["files"] if f["status"] == "gate"}
    assert set(failed) == set(BROKEN) | gates
    assert int(suite.get("failures")) == len(failed)
    for name, reason in BROKEN.items():
        assert reason in failed[name].get("message") and failed[name].get("type") == "error"
    for c in cases:
        float(c.get("time"))


def test_batch_summary_table(batch):
    text = batch["result"].stderr
    assert "gap before -> after" in text and "total 7 files" in text
    for rel in list(GOOD) + list(BROKEN):
        assert rel in text


def test_batch_survives_segfault_and_hang(tmp_path):
    """Test-only faults (WATERTIGHT_TEST_FAULT): each fails its own file, the others convert."""
    src = make_input(tmp_path / "in", good={"sphere.step": "sphere.step", "torus.step": "torus.step",
                                            "open_sheet.step": "open_sheet.step"}, broken={})
    out = tmp_path / "out"
    result = run("convert", src, "-o", out, "--jobs", 2, "--timeout", 6, "--report", tmp_path / "r.json",
                 env={"WATERTIGHT_TEST_FAULT": "segv:torus.step|hang:open_sheet.step"})
    assert result.exit_code == EXIT_FAILED, result.output
    files = {f["path"]: f for f in json.loads((tmp_path / "r.json").read_text())["files"]}
    assert files["torus.step"]["failure"] == "crash" and "SIGSEGV" in files["torus.step"]["reason"]
    assert files["open_sheet.step"]["failure"] == "timeout"
    assert "timed out after 6 s" in files["open_sheet.step"]["reason"]
    assert files["sphere.step"]["status"] in ("ok", "gate")
    assert len(error_lines(result)) == 2
    # the hanging worker had made its temporary file (.open_sheet.XXXXXXXX.step): removed when killed
    assert sorted(p.name for p in out.iterdir()) == ["sphere.step"]


def test_batch_survives_a_memory_hog(tmp_path):
    src = make_input(tmp_path / "in", good={"sphere.step": "sphere.step"}, broken={})
    result = run("convert", src, "-o", tmp_path / "out", "--max-memory", "600M", "--timeout", 120, "-q",
                 "--json", env={"WATERTIGHT_TEST_FAULT": "oom:sphere.step"})
    assert result.exit_code == EXIT_FAILED, result.output
    (f,) = json.loads(result.stdout)["files"]
    assert f["failure"] == "memory" and "memory" in f["reason"]
    assert not list((tmp_path / "out").iterdir())


def test_refuses_output_equal_to_input(tmp_path):
    src = make_input(tmp_path / "in", good={"sphere.step": "sphere.step"}, broken={})
    before = digests(src)
    result = run("convert", src, "-o", src)
    assert result.exit_code == EXIT_USAGE
    assert "would overwrite the input" in error_lines(result)[0]
    # the single-file form too (it replaces existing outputs by default, never its input)
    result = run("convert", src / "sphere.step", src / "sphere.step")
    assert result.exit_code == EXIT_USAGE
    assert "would overwrite the input" in error_lines(result)[0]
    assert digests(src) == before


def test_refuses_existing_outputs_without_overwrite_and_globs(tmp_path):
    src = make_input(tmp_path / "in", good={"sphere.step": "sphere.step", "torus.step": "torus.step"},
                     broken={})
    out = tmp_path / "out"
    out.mkdir()
    (out / "sphere.step").write_text("keep me")
    pattern = str(src / "sph*.step")  # a glob, expanded by watertight (quoted in a shell)
    result = run("convert", pattern, "-o", out, "-q", "--stage", "untrim")
    assert result.exit_code == EXIT_FAILED
    assert "exists (use --overwrite" in error_lines(result)[0]
    assert (out / "sphere.step").read_text() == "keep me"
    result = run("convert", pattern, "-o", out, "-q", "--stage", "untrim", "--overwrite")
    assert result.exit_code == EXIT_OK, result.output
    assert (out / "sphere.step").read_text().startswith("ISO-10303-21")
    assert sorted(p.name for p in out.iterdir()) == ["sphere.step"]  # the glob did not take torus


def test_batch_gate_exit_3_and_junit_failure(tmp_path):
    src = make_input(tmp_path / "in", good={"sphere.step": "sphere.step"}, broken={})
    result = run("convert", src, "-o", tmp_path / "out", "-q", "--max-deviation", "1e-30",
                 "--junit", tmp_path / "j.xml", "--format", "iges")
    assert result.exit_code == EXIT_GATE, result.output
    assert "--max-deviation" in error_lines(result)[0]
    assert (tmp_path / "out" / "sphere.igs").exists()  # --format iges; the file is kept, as single-file
    case = ET.parse(tmp_path / "j.xml").getroot().find("testsuite/testcase")
    assert case.find("failure").get("type") == "gate"


@pytest.mark.parametrize("args, words", [
    (["a.step", "b.step", "c.step"], "IN OUT, or IN... -o OUTDIR"),
    ([".", "b.step"], "is a folder (the batch form is IN... -o OUTDIR)"),
    (["a.step", "b.step", "--jobs", "2"], "--jobs needs the batch form"),
    (["a.step", "-o", "out", "--executor", "dask"], "needs --scheduler"),
    (["a.step", "-o", "out", "--scheduler", "tcp://x:1"], "needs --executor dask"),
])
def test_usage_errors(tmp_path, monkeypatch, args, words):
    monkeypatch.chdir(tmp_path)
    result = run("convert", *args)
    assert result.exit_code == EXIT_USAGE
    assert words in error_lines(result)[0]


def test_max_memory_sizes():
    from watertight_cli.cli import _Size

    size = _Size()
    assert size.convert("2G", None, None) == 2 * 2**30
    assert size.convert("512MiB", None, None) == 512 * 2**20
    assert size.convert("300", None, None) == 300 * 2**20
    result = run("convert", "a.step", "-o", "out", "--max-memory", "nan")
    assert result.exit_code == EXIT_USAGE and "Traceback" not in result.output


def test_missing_dask_is_one_line_exit_2(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    result = run("convert", fixture_path("sphere.step"), "-o", tmp_path / "out", "--executor", "dask",
                 "--scheduler", "tcp://127.0.0.1:1")
    assert result.exit_code == EXIT_USAGE
    assert "pip install 'watertight_cli[dask]'" in error_lines(result)[0]


def test_help_documents_batch_and_exit_codes():
    result = run("convert", "--help")
    assert result.exit_code == 0
    for word in ("-o, --output-dir", "--recursive", "--format", "--jobs", "--timeout", "--max-memory",
                 "--report", "--junit", "--executor", "--scheduler", "Exit codes", "0  all files",
                 "1  some file failed", "2  usage error", "3  a gate"):
        assert word in result.output, word


# ------------------------------------------------------------------------------ planning (no conversion)


def test_plan_folders_globs_and_mirrors(tmp_path):
    src = tmp_path / "in"
    for rel in ("a.step", "b.igs", "notes.txt", "sub/c.stp", "sub/deep/d.iges", ".hidden.step"):
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        (src / rel).write_text("x")
    out = tmp_path / "out"
    flat, _ = plan([str(src)], str(out))
    assert [j.rel for j in flat] == ["a.step", "b.igs"]
    deep, _ = plan([str(src)], str(out), recursive=True)
    assert [j.rel for j in deep] == ["a.step", "b.igs", "sub/c.stp", "sub/deep/d.iges"]
    assert deep[3].dst == str((out / "sub/deep/d.iges").resolve())
    globbed, _ = plan([str(src / "**" / "*.st*")], str(out), recursive=True)
    assert [j.rel for j in globbed] == ["a.step", "sub/c.stp"]
    iges, _ = plan([str(src)], str(out), recursive=True, fmt="iges")
    assert [j.rel for j in iges] == ["a.igs", "b.igs", "sub/c.igs", "sub/deep/d.igs"]
    jobs, failed = plan([str(src / "a.step"), str(tmp_path / "nope.step"), str(src / "*.xyz")], str(out))
    assert [j.rel for j in jobs] == ["a.step"]
    assert [f.failure for f in failed] == ["missing", "missing"]


def test_plan_refusals(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a.step").write_text("x")
    (src / "a.stp").write_text("x")
    with pytest.raises(UsageError, match="would overwrite the input"):
        plan([str(src)], str(src), fmt="step")
    with pytest.raises(UsageError, match="both"):
        plan([str(src)], str(tmp_path / "out"), fmt="step")  # a.step and a.stp -> out/a.step
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "a.step").write_text("old")
    jobs, failed = plan([str(src / "a.step")], str(tmp_path / "out"))
    assert not jobs and failed[0].failure == "exists"
    jobs, failed = plan([str(src / "a.step")], str(tmp_path / "out"), overwrite=True)
    assert len(jobs) == 1 and not failed


def test_plan_skips_the_output_folder_inside_the_input(tmp_path):
    (tmp_path / "a.step").write_text("x")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "a.step").write_text("x")  # an earlier run's output
    jobs, failed = plan([str(tmp_path)], str(tmp_path / "out"), recursive=True, overwrite=True)
    assert [j.rel for j in jobs] == ["a.step"] and not failed


def test_remove_temp_files(tmp_path):
    names = [".part.ab12_xyz.step", ".part.ab12_xyz.igs", ".other.ab12_xyz.step", "part.step",
             ".part.step"]
    for n in names:
        (tmp_path / n).write_text("x")
    removed = remove_temp_files(str(tmp_path / "part.step"))
    assert [Path(p).name for p in removed] == [".part.ab12_xyz.step"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names[1:])


# ------------------------------------------------------------------------------ Dask


def test_dask_local_cluster_matches_a_local_run(batch, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, host="127.0.0.1",
                                  protocol="tcp", dashboard_address=None) as cluster:
        result = run("convert", batch["src"], "-o", tmp_path / "out", "--recursive", "-q",
                     "--executor", "dask", "--scheduler", cluster.scheduler_address, "--json")
    assert result.exit_code == batch["result"].exit_code, result.output
    keys = ("path", "status", "failure", "faces", "patches")

    def summary(doc):
        return sorted(tuple(f[k] for k in keys) for f in doc["files"])

    doc = json.loads(result.stdout)
    assert doc["options"]["executor"] == "dask"
    assert summary(doc) == summary(batch["doc"])
    assert digests(tmp_path / "out").keys() == digests(batch["out"]).keys()


# ------------------------------------------------------------------------------ the real corpus (slow)


@pytest.mark.slow
def test_corpus_folder_batch(tmp_path):
    """The acceptance run: corpus files, the fixtures and three broken files in one folder, --jobs 2.

    The folder holds symbolic links (the corpus is never copied)."""
    if not CORPUS.is_dir():
        pytest.skip("../shared/corpus missing")
    src = tmp_path / "in"
    src.mkdir()
    models = [p for p in sorted(CORPUS.iterdir()) if p.suffix.lower() in (".step", ".stp", ".igs", ".iges")]
    fixtures = [p for p in sorted(fixture_path("sphere.step").parent.iterdir())
                if p.is_file() and p.suffix.lower() in (".step", ".stp", ".igs", ".iges")]
    for p in models + fixtures:
        (src / p.name).symlink_to(p)
    for name in BROKEN:
        shutil.copyfile(fixture_path(f"broken/{name}"), src / name)
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in src.iterdir()}
    out = tmp_path / "out"
    result = run("convert", src, "-o", out, "--jobs", 2, "--report", tmp_path / "r.json",
                 "--junit", tmp_path / "j.xml", "-q")
    assert result.exit_code == EXIT_FAILED, result.output
    doc = json.loads((tmp_path / "r.json").read_text())
    ET.parse(tmp_path / "j.xml")
    files = {f["path"]: f for f in doc["files"]}
    assert {n for n, f in files.items() if f["status"] == "failed"} == set(BROKEN), \
        [f["reason"] for f in files.values() if f["status"] == "failed"]
    assert len(error_lines(result)) == len(BROKEN) + sum(f["status"] == "gate" for f in files.values())
    for p in models + fixtures:
        assert (out / p.name).is_file()
    assert {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in src.iterdir()} == before


def test_sigterm_leaves_no_worker_and_no_temporary_file(tmp_path):
    """A cancelled CI job: SIGTERM to the batch kills its workers and removes their temporary files."""
    import os
    import signal
    import subprocess
    import sys
    import time

    src = make_input(tmp_path / "in", good={"open_sheet.step": "open_sheet.step"}, broken={})
    out = tmp_path / "out"
    env = dict(os.environ, WATERTIGHT_TEST_FAULT="hang:open_sheet.step")
    proc = subprocess.Popen([sys.executable, "-m", "watertight_cli.cli", "convert", str(src), "-o", str(out),
                             "-q", "--jobs", "1"], env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (out.exists() and any(out.iterdir())):
        time.sleep(0.2)  # the hanging worker has made its temporary file
    assert out.exists() and any(out.iterdir()), "the worker never started"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=30) == 128 + signal.SIGTERM
    assert list(out.iterdir()) == []


def test_durations_order_the_next_batch(tmp_path):
    """Files start longest first: by their last run's time when known, else by size (scaled by the
    batch's median seconds per byte); the times live in WATERTIGHT_CACHE_DIR (conftest)."""
    from watertight_cli.batch import FileResult, Job, durations_file, estimates, record_durations

    paths = []
    for name, size in (("big.step", 1000), ("small.step", 10), ("new.step", 2000)):
        p = tmp_path / name
        p.write_bytes(name.encode() * (size // len(name)) + b"x" * (size % len(name)))
        paths.append(p)
    jobs = [Job(str(p), str(p), p.name, str(tmp_path / "out" / p.name), p.name, {"stage": "full"})
            for p in paths]
    assert estimates(jobs) == [1000.0, 10.0, 2000.0]  # nothing known yet: by size
    record_durations(jobs[:2], [FileResult("big", "big", "big", report={}, elapsed=1.0),
                                FileResult("small", "small", "small", report={}, elapsed=50.0)])
    assert durations_file().is_file()
    est = estimates(jobs)
    assert est[:2] == [1.0, 50.0]  # the small file took longer: it starts first
    assert est[2] == pytest.approx(2000 * (1 / 1000 + 50 / 10) / 2)  # median seconds per byte
    # a failed file is not recorded, and another stage is another key
    record_durations(jobs[2:], [FileResult("new", "new", "new", failure="crash", elapsed=3.0)])
    assert estimates(jobs)[2] == pytest.approx(2000 * (1 / 1000 + 50 / 10) / 2)
    other = [Job(j.shown, j.src, j.rel, j.dst, j.dst_shown, {"stage": "untrim"}) for j in jobs]
    assert estimates(other) == [1000.0, 10.0, 2000.0]
