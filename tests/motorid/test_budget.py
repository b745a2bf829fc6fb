"""Absurd sizes are refused before any work starts, with the estimate that refused them."""
import pytest

from motorid.budget import SIMULATE_BYTES_PER_SAMPLE, SWEEP_BYTES_PER_SAMPLE, format_bytes, parse_memory
from motorid.cli import main
from scenarios.scenario import MAX_GRID_POINTS


def test_simulate_of_a_huge_duration_is_refused_with_the_estimate(tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--duration", "1e7", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"about {format_bytes(2e9 * SIMULATE_BYTES_PER_SAMPLE)} of memory" in err and "--max-memory" in err
    assert not out.exists()


def test_simulate_honours_max_memory_both_ways(tmp_path, capsys):
    out = tmp_path / "r.csv"
    argv = ["simulate", "--a", "25", "--b", "3", "--duration", "1", "--out", str(out)]
    assert main([*argv, "--max-memory", "10K"]) == 2 and not out.exists()   # 200 samples * 250 B = 49 KiB
    assert main([*argv, "--max-memory", "1M"]) == 0 and out.exists()


def _scenario(tmp_path, repetitions, grid):
    path = tmp_path / "s.toml"
    path.write_text(f'name = "s"\nrepetitions = {repetitions}\nmethods = ["zoh-ls"]\n[bench]\nduration = 1.0\n'
                    f'[grid]\n"excitation.frequency" = {grid}\n', encoding="utf-8")
    return path


def test_a_sweep_of_1e12_repetitions_is_refused_with_the_estimate(tmp_path, capsys):
    path = _scenario(tmp_path, 10**12, "[10.0]")
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--quiet", "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert f"about {format_bytes(1e12 * 200 * SWEEP_BYTES_PER_SAMPLE)} of memory" in err
    assert not (tmp_path / "o").exists()


def test_a_grid_over_the_limit_is_refused_before_its_points_are_validated(tmp_path, capsys):
    n = int(MAX_GRID_POINTS ** 0.5) + 1
    path = tmp_path / "g.toml"
    values = "[" + ",".join(str(10 + k * 1e-3) for k in range(n)) + "]"
    path.write_text(f'name = "g"\nrepetitions = 1\nmethods = ["zoh-ls"]\n[grid]\n"excitation.frequency" = {values}\n'
                    f'"bench.angle_noise" = [' + ",".join(str(k * 1e-7) for k in range(n)) + "]\n", encoding="utf-8")
    assert main(["sweep", str(path), "--out", str(tmp_path / "o"), "--quiet", "--no-plots"]) == 2
    assert f"the grid has {n * n:,} points, over the {MAX_GRID_POINTS:,}" in capsys.readouterr().err


@pytest.mark.parametrize("text, value", [("512", 512), ("4K", 4096), ("1.5G", 3 << 29), ("8GiB", 8 << 30)])
def test_max_memory_sizes(text, value):
    assert parse_memory(text) == value
