"""The self-contained HTML pages of ``report --html`` and ``convert --html``."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest
from click.testing import CliRunner

from watertight_cli.cli import EXIT_FAILED, EXIT_OK, main
from watertight_cli.html_report import Scene, decimate, limit_segments, refine, render, write_html

from .conftest import corpus_path, fixture_path

IMG = re.compile(r'<img src="data:image/(png|svg\+xml);base64,([A-Za-z0-9+/=]+)"')


def run(*args):
    return CliRunner().invoke(main, list(args), catch_exceptions=False)


def assert_self_contained(text: str) -> None:
    """No URL of any kind: base64 has no ':' so a scheme cannot hide in the figures."""
    assert re.search(r"https?:", text, re.IGNORECASE) is None
    assert re.search(r"(src|href)\s*=\s*[\"']?(//|[a-z]+:(?!image/))", text, re.IGNORECASE) is None
    assert "url(" not in text and "@import" not in text and "<script" not in text.lower()
    assert "<link" not in text.lower()


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    d = tmp_path_factory.mktemp("html")
    page = d / "convert.html"
    src = fixture_path("two_solids.step")
    result = run("convert", str(src), str(d / "out.step"), "-q", "--html", str(page))
    assert result.exit_code == EXIT_OK, result.output
    return page


def test_convert_page_is_self_contained(converted):
    text = converted.read_text(encoding="utf-8")
    figures = IMG.findall(text)
    assert len(figures) >= 3
    assert_self_contained(text)
    # the two pictures (PNG), before and after, differ
    pictures = [data for kind, data in figures if kind == "png"]
    assert len(pictures) == 2 and pictures[0] != pictures[1]
    for words in ("Gap distribution", "Worst edges", "before: input faces", "after: Bezier patches",
                  "Degrees, patches and deviation", "Settings and times"):
        assert words in text
    # worst edges come with their location
    assert "<th>x</th><th>y</th><th>z</th>" in text
    assert not list(converted.parent.glob(".convert*"))  # no temporary file left


def test_convert_json_has_per_edge_gaps_before_and_after(tmp_path):
    import json

    src = fixture_path("sphere_cut_box.step")
    result = run("convert", str(src), str(tmp_path / "o.step"), "-q", "--json")
    assert result.exit_code == EXIT_OK, result.output
    rep = json.loads(result.stdout)
    for side in ("before", "after"):
        rows = rep[side]["edge_gaps"]
        assert rows and all(len(r["where"]) == 3 for r in rows)
        gaps = [r["gap"] for r in rows]
        assert gaps == sorted(gaps, reverse=True)
        assert gaps[0] == pytest.approx(rep[side]["gap_max"])


def test_report_page(tmp_path):
    page = tmp_path / "r.html"
    result = run("report", str(fixture_path("sphere_cut_box.step")), "-q", "--html", str(page))
    assert result.exit_code == EXIT_OK, result.output
    text = page.read_text(encoding="utf-8")
    assert len(IMG.findall(text)) >= 2  # histogram and picture
    assert_self_contained(text)
    assert "Worst edges" in text and "after (read back)" not in text


def test_report_page_names_failed_file(tmp_path):
    page = tmp_path / "r.html"
    result = run("report", str(fixture_path("broken/garbage.step")), str(fixture_path("sphere.step")), "-q",
                 "--html", str(page))
    assert result.exit_code == EXIT_FAILED
    text = page.read_text(encoding="utf-8")
    assert "garbage.step" in text and "sphere.step" in text


def test_unwritable_html_is_one_line_error(tmp_path):
    result = run("report", str(fixture_path("sphere.step")), "-q", "--html", str(tmp_path / "no" / "r.html"))
    assert result.exit_code == EXIT_FAILED
    assert "Traceback" not in result.output
    errors = [ln for ln in result.output.splitlines() if ln.startswith("watertight: error:")]
    assert len(errors) == 1 and "does not exist" in errors[0]


def test_write_html_is_atomic(tmp_path, monkeypatch):
    target = tmp_path / "p.html"
    target.write_text("old")

    class Boom(Exception):
        pass

    def fail(*_a, **_k):
        raise Boom

    monkeypatch.setattr("os.replace", fail)
    with pytest.raises(Boom):
        write_html(target, "<html>new</html>")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["p.html"]


def _grid_scene(n: int) -> Scene:
    """A wavy sheet of 2 (n-1)^2 triangles in 4 groups, with a gap-coloured border."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    p = np.stack([x, y, 0.1 * np.sin(6 * x) * np.cos(4 * y)], axis=-1)
    a, b, c, d = p[:-1, :-1], p[1:, :-1], p[1:, 1:], p[:-1, 1:]
    tris = np.concatenate([np.stack(t, -2).reshape(-1, 3, 3) for t in ((a, b, c), (a, c, d))])
    groups = (tris[:, 0, 0] > 0.5).astype(int) + 2 * (tris[:, 0, 1] > 0.5)
    border = p[0]
    edges = np.stack([border[:-1], border[1:]], axis=1)
    return Scene(triangles=tris, groups=groups, edges=edges, edge_values=np.logspace(-9, -3, len(edges)))


def test_decimate_keeps_extent_and_budget():
    scene = _grid_scene(301)  # 180k triangles
    tris, groups = decimate(scene.triangles, scene.groups, 20_000)
    assert 1000 < len(tris) <= 20_000 and len(groups) == len(tris)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    assert np.allclose(lo[:2], 0, atol=0.02) and np.allclose(hi[:2], 1, atol=0.02)
    assert set(np.unique(groups)) == {0, 1, 2, 3}
    small, _ = decimate(scene.triangles[:10], scene.groups[:10], 20_000)
    assert len(small) == 10


def test_refine_and_limits():
    big = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=float)
    tris, groups = refine(big, np.array([7]), 0.3, 1000)
    assert len(tris) > 1 and set(groups) == {7}
    assert np.isclose(sum(0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) for t in tris), 0.5)
    segs = np.zeros((100, 2, 3))
    vals = np.arange(100.0)
    kept, kv = limit_segments(segs, vals, 10)
    assert len(kept) == 10 and kv.min() == 90
    kept, kv = limit_segments(segs, None, 10)
    assert len(kept) == 10 and kv is None


def test_render_large_scene_is_fast():
    """A scene the size of a 40k-patch corpus file renders in seconds (decimated)."""
    import time

    scene = _grid_scene(201)  # 80k triangles
    scene.lines = np.random.default_rng(1).random((160_000, 2, 3))
    t = time.perf_counter()
    uri, notes = render(scene, "big", (1e-9, 1e-3), True)
    assert time.perf_counter() - t < 30
    assert uri.startswith("data:image/png;base64,")
    assert any("decimated" in n for n in notes) and any("patch-boundary" in n for n in notes)


@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium not installed")
def test_chromium_screenshot_not_blank(converted, tmp_path):
    shot = tmp_path / "shot.png"
    subprocess.run(["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
                    "--window-size=1200,3000", converted.as_uri()],
                   capture_output=True, timeout=120, check=False)
    assert shot.exists() and shot.stat().st_size > 0
    import matplotlib.image

    img = matplotlib.image.imread(str(shot))[..., :3]
    # not blank: many distinct colours and a good share of non-white pixels
    assert (img.reshape(-1, 3) < 0.9).any(axis=1).mean() > 0.05
    assert len(np.unique((img.reshape(-1, 3) * 255).astype(np.uint8), axis=0)) > 100


@pytest.mark.slow
def test_corpus_convert_page(tmp_path):
    """bug24595 converts to ~40k patches; the page is still written and self-contained."""
    src = corpus_path("occt__bug24595_281390.stp")
    page = tmp_path / "c.html"
    result = run("convert", str(src), str(tmp_path / "o.step"), "-q", "--html", str(page))
    assert result.exit_code in (0, 3), result.output
    text = page.read_text(encoding="utf-8")
    assert len(IMG.findall(text)) >= 4
    assert_self_contained(text)


@pytest.mark.parametrize("option", ["--fast", "--stage=untrim"])
def test_convert_page_without_read_back(tmp_path, option):
    page = tmp_path / "c.html"
    result = run("convert", str(fixture_path("sphere.step")), str(tmp_path / "o.step"), option, "-q",
                 "--html", str(page))
    assert result.exit_code == EXIT_OK, result.output
    text = page.read_text(encoding="utf-8")
    assert len(IMG.findall(text)) >= 4
    assert "not read back" in text
    assert_self_contained(text)


def test_clip_segments_to_box():
    from watertight_cli.html_report import clip_segments

    segs = np.array([[[-1, 0.5, 0.5], [2, 0.5, 0.5]],   # crosses the box
                     [[0.2, 0.2, 0.2], [0.4, 0.4, 0.4]],  # inside
                     [[2, 2, 2], [3, 3, 3]]], dtype=float)  # outside
    out, vals = clip_segments(segs, np.array([1.0, 2.0, 3.0]), np.zeros(3), np.ones(3))
    assert list(vals) == [1.0, 2.0]
    assert np.allclose(out[0], [[0, 0.5, 0.5], [1, 0.5, 0.5]]) and np.allclose(out[1], segs[1])
