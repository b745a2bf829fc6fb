"""motorid demo: the article's Table 1, every method, against the truth."""
import json

import pytest

from identify import available_methods, fit
from motorid.cli import main
from motorsim import read_recording


def test_demo_table_matches_direct_fits_of_its_recordings(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--duration", "2", "--out", str(out), "--no-plots"]) == 0
    text = capsys.readouterr().out
    assert "true a" in text and "eta_4" in text
    table = json.loads((out / "table.json").read_text())
    assert table["true_a"] == 25.0 and table["true_b"] == 3.0
    rows = table["rows"]
    assert len(rows) == 4 * len(available_methods(open_loop=True, first_order=True))
    for row in rows:
        i = int(row["input"].split("_")[1])
        rec = read_recording(out / f"eta_{i}.csv")
        assert rec.metadata["excitation"] == f"sine:{[10.0, 20.0, 30.0, 40.0][i - 1]!r},200,0.0"
        est = fit(rec, method=row["method"])
        assert row["a"] == pytest.approx(est.a, rel=1e-12) and row["b"] == pytest.approx(est.b, rel=1e-12)
    # the article's method is biased low in a, and more so at higher input frequency
    euler = [r["a"] for r in rows if r["method"] == "euler-ls"]
    assert all(a < 25 for a in euler) and euler == sorted(euler, reverse=True)


def test_demo_writes_the_figures(tmp_path, capsys, monkeypatch):
    from motorid import plots
    figures = {}

    def keep(name):
        original = getattr(plots, name)

        def wrapper(*args, **kwargs):
            figures.setdefault(name, []).append(original(*args, **kwargs))
            return figures[name][-1]
        monkeypatch.setattr(plots, name, wrapper)
    keep("plot_run")
    keep("plot_overlay")
    out = tmp_path / "demo"
    assert main(["demo", "--duration", "1", "--frequencies", "10,20", "--out", str(out)]) == 0
    for name in ("figure_1.png", "figure_2.png", "overlay.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [f.get_suptitle() for f in figures["plot_run"]] == [
        "Figure 1: eta_1 = 200 sin(10 t) and the measured speed ω",
        "Figure 2: eta_2 = 200 sin(20 t) and the measured speed ω"]
    (overlay,) = figures["plot_overlay"]
    assert [ax.get_title(loc="left") for ax in overlay.axes] == ["eta_1 = 200 sin(10 t)", "eta_2 = 200 sin(20 t)"]
    for ax in overlay.axes:   # measured, euler-ls and oe on every panel
        assert [t.get_text().split(":")[0] for t in ax.get_legend().get_texts()] == ["measured ω", "euler-ls", "oe"]


def test_demo_rejects_unknown_methods(tmp_path, capsys):
    assert main(["demo", "--methods", "nope", "--out", str(tmp_path)]) == 2
    assert "--methods must name methods among" in capsys.readouterr().err
