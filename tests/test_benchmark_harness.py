"""benchmarks/harness.py's statistics and report helpers against hand-computed values (no solves, no
timing)."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import harness as h  # noqa: E402


def test_stats_match_numpy():
    xs = [4.0, 1.0, 3.0, 10.0, 2.0]
    s = h.stats(xs)
    assert (s.n, s.median, s.worst, s.best) == (5, 3.0, 10.0, 1.0)
    assert s.p90 == pytest.approx(np.percentile(xs, 90)) == pytest.approx(7.6)  # 4 + 0.6 * (10 - 4)
    assert s.p95 == pytest.approx(8.8)
    assert s.worst_over_median == pytest.approx(10 / 3)
    assert np.isnan(h.stats([]).median) and np.isnan(h.median([]))


def test_ratios():
    assert h.ratio_of_medians([2.0, 4.0, 6.0], [1.0, 2.0, 10.0]) == pytest.approx(2.0)
    assert h.median_ratio([2.0, 4.0, 6.0], [1.0, 2.0, 10.0]) == pytest.approx(2.0)  # 2, 2, 0.6
    assert h.geomean([1.0, 4.0]) == pytest.approx(2.0) and np.isnan(h.geomean([]))


def test_report_helpers(tmp_path):
    assert h.row("a", 1, "x y") == "| a | 1 | x y |"
    assert h.table(["T", "median [ms]"], [(20, "1.5"), "| 40 | 3.0 |"]) == [
        "| T | median [ms] |", "|---|---|", "| 20 | 1.5 |", "| 40 | 3.0 |"]
    assert h.key_values(T=20, median_ms="1.5") == "T=20 median_ms=1.5"
    assert h.last_line("worst_case", "T=20 a=1", "T=40 a=2") == "worst_case: T=20 a=1 | T=40 a=2"
    out = h.write_result(tmp_path / "r.md", "x\n")
    assert out == tmp_path / "r.md" and out.read_text() == "x\n"


def test_parser_common_options():
    args = h.parser("Doc.\n\nMore.", configs=100, seed=0, horizons=[20, 40]).parse_args(
        ["--configs", "2", "--horizons", "10"])
    assert (args.configs, args.seed, args.horizons) == (2, 0, [10])
    assert not hasattr(h.parser(None).parse_args([]), "configs")
