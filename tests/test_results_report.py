"""The benchmark report: RESULTS.md assembly from benchmark pages, and the growth fit of the scaling benchmark."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import run_all  # noqa: E402
from bench_scaling import fit_growth  # noqa: E402

EXTRACT_PAGE = """# Source motion extraction on synthetic scenes

`python benchmarks/bench_extract.py` made this.

## Summary

| motion | noise (px) | median rotation (deg) | median centroid (% radius) | mean time (s) |
|---|---|---|---|---|
| translation | 0 | 0.47 | 5.32 | 1.0 |
| translation | 1 | 2.27 | 5.33 | 1.1 |
| hinge | 0 | 0.19 | 4.67 | 2.0 |
| hinge | 1 | 0.18 | 5.03 | 2.1 |

On exact tracks:

| motion | noise (px) | rotation, LK tracks (deg) | rotation, exact tracks (deg) | centroid, exact tracks (% radius) |
|---|---|---|---|---|
| translation | 0 | 0.47 | 0.00 | 6.09 |
| translation | 1 | 2.27 | 1.14 | 6.44 |
"""

TABLE1_PAGE = """# Table 1

| category | clip | PSNR (dB) | SSIM | LPIPS | paper SpaT PSNR / SSIM / LPIPS |
|---|---|---|---|---|---|
| single-slow | davis_car-shadow | 21.94 | 0.948 | skipped | 19.08 / 0.95 / 0.09 |
| extra | backpack | 18.00 | 0.900 | skipped | – |
"""

TABLE1_TARGETS_PAGE = """# Table 1

| category | clip | target | PSNR (dB) | SSIM | LPIPS | paper SpaT PSNR / SSIM / LPIPS |
|---|---|---|---|---|---|---|
| single-slow | davis_car-shadow | reconstruction | 26.50 | 0.970 | 0.030 | 19.08 / 0.95 / 0.09 |
| single-slow | davis_car-shadow | held-out | 25.00 | 0.960 | 0.040 | 19.08 / 0.95 / 0.09 |
| single-slow | davis_car-shadow | frame0 | 22.27 | 0.952 | skipped | 19.08 / 0.95 / 0.09 |
| single-fast | davis_car-turn | reconstruction | 27.00 | 0.975 | 0.050 | 25.88 / 0.98 / 0.02 |
| extra | backpack | reconstruction | 18.00 | 0.900 | 0.300 | – |
"""

SCALING_PAGE = """# Scaling

Extraction grows as T^1.05 (FAKE-SCALING-MARKER).

![plot](../images/results/scaling_frames.png)
"""


PAPER_SETTING_PAGE = """# The paper's setting end to end

| stage (paper's Table 2 rows) | paper, RTX A6000 | ours, CPU | ratio |
|---|---:|---:|---:|
| **total** | **26.8 min** | **42.0 s** | **38×** |
"""

DOCS = Path(__file__).resolve().parents[1] / "docs"


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("report")
    bench = tmp_path / "docs" / "benchmarks"
    bench.mkdir(parents=True)
    (bench / "extract.md").write_text(EXTRACT_PAGE)
    (bench / "scaling.md").write_text(SCALING_PAGE)
    (bench / "table1.md").write_text(TABLE1_PAGE)
    (bench / "paper_setting.md").write_text(PAPER_SETTING_PAGE)
    (bench / "new_question.md").write_text("# A page in no group\n\nFAKE-DETAIL-MARKER\n")
    out = tmp_path / "docs" / "RESULTS.md"
    text = run_all.assemble(bench, out, tmp_path / "docs" / "images" / "results", info={"CPU": "Test CPU 9000"},
                            date="2026-01-02 03:04 UTC", skipped={"bench_memory.py": "failed (exit code 1)"})
    return text, out, tmp_path


def test_assemble_has_the_headline_tables_and_the_machine(report):
    text, out, _ = report
    assert out.read_text() == text
    for title, *_ in run_all.HEADLINES:
        assert f"\n## {title}\n" in text
    assert "Test CPU 9000" in text and "2026-01-02 03:04 UTC" in text
    table1 = text[text.index("\n## Table 1"):text.index("\n## Pose accuracy")]
    assert "| single-slow | davis_car-shadow | 21.94 | 0.948 | skipped | 19.08 / 0.95 / 0.09 |" in table1
    pose = text[text.index("\n## Pose accuracy"):text.index("\n## Speed")]
    assert "| hinge | 1 | 0.18 | 5.03 |" in pose  # the summary table, cut to the columns shown
    assert "| translation | 0 | 0.47 | 0.00 | 6.09 |" not in pose  # not the exact-track table
    assert "| **total** | **26.8 min** | **42.0 s** | **38×** |" in text
    assert "_Not run: `rasterizer.md` is missing" in text


def test_assemble_links_every_page_once_and_keeps_the_detail_there(report):
    text, _, tmp_path = report
    for page in (tmp_path / "docs" / "benchmarks").glob("*.md"):
        assert text.count(f"](benchmarks/{page.name})") == 1 + (f"Details: [`{page.name}`]" in text), page.name
    assert "- [`new_question.md`](benchmarks/new_question.md): A page in no group" in text
    assert "FAKE-DETAIL-MARKER" not in text and "FAKE-SCALING-MARKER" not in text


def test_assemble_lists_missing_pages_as_not_run(report):
    text, _, _ = report
    not_run = text[text.index("Not run:"):text.index("\n## ")]
    assert "`memory.md` (`benchmarks/bench_memory.py`): failed (exit code 1)" in not_run
    assert "`rasterizer.md` (`benchmarks/bench_rasterizer.py`): no page yet" in not_run
    for page in ("table1.md", "extract.md", "scaling.md", "paper_setting.md"):
        assert f"`{page}`" not in not_run


def test_the_summary_of_the_real_pages_is_short_and_links_them_all(tmp_path):
    """The pages in the repository, assembled: at most 15 KB, every page linked, the headline tables there.
    Also the committed RESULTS.md links every page (it was re-assembled since a page was added)."""
    bench = tmp_path / "docs" / "benchmarks"
    bench.mkdir(parents=True)
    for page in (DOCS / "benchmarks").glob("*.md"):
        (bench / page.name).write_text(page.read_text())
    text = run_all.assemble(bench, tmp_path / "docs" / "RESULTS.md", tmp_path / "docs" / "images" / "results",
                            info=run_all.machine(), date="now")
    assert len(text.encode()) <= 15_000
    assert "_Not run:" not in text  # every headline table found on its page
    committed = (DOCS / "RESULTS.md").read_text()
    assert len(committed.encode()) <= 15_000
    for page in (DOCS / "benchmarks").glob("*.md"):
        assert f"](benchmarks/{page.name})" in text and f"](benchmarks/{page.name})" in committed, page.name


@pytest.mark.parametrize("name", ["pose_accuracy.png", "table1.png"])
def test_assemble_draws_plots_from_the_tables(report, name):
    text, _, tmp_path = report
    assert (tmp_path / "docs" / "images" / "results" / name).stat().st_size > 1000
    assert f"](images/results/{name})" in text


def test_pose_accuracy_panels_read_the_summary_and_the_exact_track_tables():
    panels = run_all.pose_accuracy_panels(EXTRACT_PAGE)
    assert [label for label, _ in panels] == ["rotation error (deg)", "rotation error, exact tracks (deg)",
                                             "centroid error (% radius)"]
    assert panels[0][1] == {"0": {"translation": 0.47, "hinge": 0.19}, "1": {"translation": 2.27, "hinge": 0.18}}
    assert panels[1][1] == {"0": {"translation": 0.0}, "1": {"translation": 1.14}}
    assert panels[2][1]["1"] == {"translation": 5.33, "hinge": 5.03}  # the summary's, not the exact table's
    assert [label for label, _ in run_all.pose_accuracy_panels(EXTRACT_PAGE.split("On exact")[0])] == [
        "rotation error (deg)", "centroid error (% radius)"]


def test_table1_series_has_a_bar_per_target_and_clip():
    clips, paper, ours = run_all.table1_series(TABLE1_TARGETS_PAGE)
    assert clips == ["davis_car-shadow", "davis_car-turn"]  # the backpack has no paper row
    assert paper["davis_car-turn"] == [25.88, 0.98, 0.02]
    assert list(ours) == ["reconstruction", "held-out", "frame0"]
    assert ours["reconstruction"]["davis_car-turn"] == [27.0, 0.975, 0.05]
    assert ours["frame0"]["davis_car-shadow"][:2] == [22.27, 0.952]
    assert np.isnan(ours["frame0"]["davis_car-shadow"][2])  # LPIPS skipped
    assert all(np.isnan(ours[t]["davis_car-turn"]).all() for t in ("held-out", "frame0"))  # not run
    # Without a target column, one series named "ours".
    _, _, single = run_all.table1_series(TABLE1_PAGE)
    assert list(single) == ["ours"] and single["ours"]["davis_car-shadow"][0] == 21.94
    assert run_all.table1_series(EXTRACT_PAGE) is None


def test_plot_table1_draws_the_targets(tmp_path):
    page = tmp_path / "table1.md"
    page.write_text(TABLE1_TARGETS_PAGE)
    assert run_all.plot_table1(page, tmp_path / "table1.png")
    assert (tmp_path / "table1.png").stat().st_size > 1000


def test_markdown_tables_drop_the_rule_and_split_cells():
    tables = run_all.markdown_tables("intro\n| a | b |\n|---|---:|\n| 1 | 2 |\n\n| c |\n|---|\n| 3 |\n")
    assert tables == [[["a", "b"], ["1", "2"]], [["c"], ["3"]]]


def test_fit_growth_recovers_a_power_law():
    sizes = np.array([50, 200, 800, 3200])
    a, c = fit_growth(sizes, 0.02 * sizes ** 1.3)
    assert a == pytest.approx(1.3, abs=1e-9) and c == pytest.approx(0.02, rel=1e-9)
    # ±5 % timing noise moves the slope by well under 0.05 over a 64-fold range of sizes.
    noisy = 0.02 * sizes ** 1.3 * np.random.default_rng(0).uniform(0.95, 1.05, sizes.size)
    assert fit_growth(sizes, noisy)[0] == pytest.approx(1.3, abs=0.05)
    assert fit_growth([1e5, 1e6], [2.0, 2.0])[0] == pytest.approx(0.0, abs=1e-12)


def test_fit_growth_needs_two_sizes():
    with pytest.raises(ValueError):
        fit_growth([100, 100], [1.0, 2.0])
    with pytest.raises(ValueError):
        fit_growth([100, 200], [1.0, 0.0])
