"""The figures docs/guide/article.md quotes hold for the command it names (``motorid demo``).

The page shows the command's tables as the docs build prints them, and quotes a few figures in
its text; each is checked here against the same run, with the tolerance written next to it.
"""
from __future__ import annotations

import pytest

from motorid.cli import main


@pytest.fixture(scope="module")
def demo_tables(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "demo-output"
    assert main(["demo", "--no-plots", "--out", str(out)]) == 0
    open_loop = {}
    for line in (out / "table.txt").read_text(encoding="utf-8").splitlines():
        words = line.split()
        if len(words) >= 10 and words[0].startswith("eta_"):
            open_loop[(words[0], words[2])] = (float(words[5]), float(words[8]))      # a err %, b err %
    closed = {}
    for line in (out / "closed_loop.txt").read_text(encoding="utf-8").splitlines():
        words = line.split()
        if len(words) == 6 and words[0] in ("truth", "euler-ls", "oe"):
            closed[words[0]] = tuple(float(w) for w in words[1:])   # a, b, predicted, measured, meas/pred
    return open_loop, closed


def test_the_articles_method_misses_a_by_12_to_24_percent(demo_tables):
    errors = [-a for (_, method), (a, _) in demo_tables[0].items() if method == "euler-ls"]
    assert len(errors) == 4
    assert 11.5 <= min(errors) and max(errors) <= 24.5          # "12-24 %", rounded to whole percent


def test_oe_lands_within_0_002_percent(demo_tables):
    errors = [max(abs(a), abs(b)) for (_, method), (a, b) in demo_tables[0].items() if method == "oe"]
    assert len(errors) == 4 and max(errors) <= 0.0025             # "within 0.002 %", as printed (3 decimals)


def test_the_closed_loop_figures(demo_tables):
    closed = demo_tables[1]
    assert abs(closed["oe"][4] - 1.0) <= 0.0015                   # "predicts its loop to 0.1 %"
    assert closed["euler-ls"][3] / closed["truth"][3] == pytest.approx(1.04, abs=0.01)   # "track 4 % worse"
    assert abs(closed["euler-ls"][4] - 1.0) == pytest.approx(0.12, abs=0.01)            # "mispredict ... by 12 %"


def test_the_designs_model_errs_by_about_12_percent(demo_tables):
    a, b = demo_tables[0][("eta_1", "euler-ls")]
    assert 11.0 <= -a <= 12.5 and 11.0 <= -b <= 12.5              # "a 12 % error in a and b", whole percent
