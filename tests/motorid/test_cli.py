"""The motorid command line, end to end: simulate -> file -> identify --json."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from motorid.cli import main
from motorsim import read_recording


def _last_json(capsys):
    return json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_simulate_then_identify_recovers_the_closed_forms(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--sample-period", "0.005", "--duration", "5",
                 "--sine", "20,200,0.4", "--record-speed", "--out", str(out)]) == 0
    rec = read_recording(out)
    assert len(rec) == 1000 and rec.counts_per_rev == 16667 and rec.metadata["excitation"] == "sine:20.0,200,0.4"
    capsys.readouterr()
    assert main(["identify", str(out), "--method", "zoh-ls", "--json"]) == 0
    res = _last_json(capsys)
    assert res["method"] == "zoh-ls" and res["n_samples"] == 999  # recorded speed: every k pairs with k+1
    assert res["a"] == pytest.approx(25, rel=1e-9) and res["b"] == pytest.approx(3, rel=1e-9)
    assert main(["identify", str(out), "--method", "euler-ls", "--json"]) == 0
    res = _last_json(capsys)
    a_e = (1 - math.exp(-25 * 0.005)) / 0.005
    assert res["a"] == pytest.approx(a_e, rel=1e-9) and res["b"] == pytest.approx(3 * a_e / 25, rel=1e-9)
    assert {"fit_percent", "a_stderr", "b_ci95"} <= set(res)


def test_identify_pools_several_files(tmp_path, capsys):
    files = []
    for f in (10, 40):
        files.append(str(tmp_path / f"s{f}.csv"))
        assert main(["simulate", "--a", "25", "--b", "3", "--duration", "2", "--sine", f"{f}", "--out",
                     files[-1]]) == 0
    capsys.readouterr()
    assert main(["identify", *files, "--method", "zoh-ls", "--json"]) == 0
    pooled = _last_json(capsys)
    assert pooled["n_samples"] == 2 * 398
    # oe pools the files into one output-error problem: not either file's answer, within 0.1 %
    # of the truth (noise-free, 16667 counts/rev: oe lands within 0.002 %), and tighter than each
    assert main(["identify", *files, "--json"]) == 0
    pooled = _last_json(capsys)
    singles = []
    for f in files:
        assert main(["identify", f, "--json"]) == 0
        singles.append(_last_json(capsys))
    assert all(abs(pooled["a"] - s["a"]) > 1e-9 for s in singles)
    assert pooled["a"] == pytest.approx(25, rel=1e-3) and pooled["b"] == pytest.approx(3, rel=1e-3)
    assert pooled["a_stderr"] < min(s["a_stderr"] for s in singles)


def test_simulate_excitation_flags(tmp_path, capsys):
    out = tmp_path / "p.csv"
    assert main(["simulate", "--a", "10", "--b", "1", "--duration", "1", "--prbs", "120,-80,7,3",
                 "--jitter", "0.1", "--drop-rate", "0.01", "--angle-noise", "0.001", "--seed", "4",
                 "--out", str(out)]) == 0
    rec = read_recording(out)
    assert set(rec.duty.tolist()) == {120, -80} and rec.metadata["jitter"] == "0.1"


@pytest.mark.parametrize("argv, message", [
    (["simulate", "--a", "-1", "--b", "3", "--out", "x.csv"], "a must be > 0, got -1.0"),
    (["simulate", "--a", "1", "--b", "3", "--sine", "10,abc", "--out", "x.csv"], "comma-separated numbers"),
    (["simulate", "--a", "1", "--b", "3", "--sample-period", "0", "--out", "x.csv"],
     "--sample-period must be in 1e-06...4294.97 s"),
    (["identify", "does-not-exist.csv"], "does-not-exist.csv: cannot read"),
], ids=["a", "sine", "dt", "missing-file"])
def test_user_errors_exit_2_with_a_message_not_a_traceback(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("motorid: error: ") and message in err and "Traceback" not in err


def test_identify_on_a_constant_input_says_why(tmp_path, capsys):
    out = tmp_path / "c.csv"
    main(["simulate", "--a", "25", "--b", "3", "--duration", "1", "--constant", "0", "--out", str(out)])
    assert main(["identify", str(out), "--method", "zoh-ls"]) == 2
    assert "not persistently exciting" in capsys.readouterr().err


def test_help_does_not_import_plotting_or_control():
    # Building the parser loads every command's flags but none of their heavy dependencies.
    code = ("import sys\nfrom motorid.cli import build_parser\nbuild_parser()\n"
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'matplotlib', 'control', 'dask'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2]).stdout
    assert out.strip() == "[]"


def _flip(tmp_path, bit, name="flip.csv"):
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine, write_recording
    rec = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(5)).run(
        Experiment(Sine(20.0), 0.005, 10.0))
    path = write_recording(rec, tmp_path / name)
    lines = path.read_text(encoding="utf-8").splitlines()
    k = lines.index("seq,time_s,duty,counts") + 1 + 1000
    row = lines[k].split(",")
    row[3] = str(int(row[3]) ^ (1 << bit))
    lines[k] = ",".join(row)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path, k + 1


@pytest.mark.parametrize("bit", [12, 40])
def test_identify_refuses_a_corrupted_sample_naming_it(tmp_path, capsys, bit):
    path, line = _flip(tmp_path, bit)
    assert main(["identify", str(path)]) == 2
    err = capsys.readouterr().err
    assert "seq 1000" in err and (f"line {line}" in err or bit == 12) and "--drop-outliers" in err


@pytest.mark.parametrize("bit", [12, 40])
def test_identify_drop_outliers_drops_and_says_so(tmp_path, capsys, bit):
    path, _ = _flip(tmp_path, bit)
    assert main(["identify", "--drop-outliers", "--json", str(path)]) == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)           # --json: stdout is exactly one JSON document
    assert captured.err.startswith(f"dropped     {path}: seq 1000 (")
    assert result["dropped_samples"] == {str(path): [1000]}
    assert abs(result["a"] - 25.0) < 0.1 and abs(result["b"] - 3.0) < 0.012   # ~3 standard errors


def test_identify_refuses_the_same_file_pooled_twice(tmp_path, capsys):
    path, _ = _flip(tmp_path, 0)
    copy = tmp_path / "copy.csv"
    copy.write_bytes(path.read_bytes())
    assert main(["identify", str(path), str(tmp_path / "." / path.name)]) == 2
    assert "same file" in capsys.readouterr().err
    assert main(["identify", str(path), str(copy)]) == 2
    assert "same content" in capsys.readouterr().err


def test_a_warning_is_one_line_naming_motorid_not_a_source_line(tmp_path, capsys):
    # the real PRBS run never reverses: oe-friction warns that friction merges into the bias
    import warnings as _warnings
    from pathlib import Path
    prbs = Path(__file__).parents[1] / "data" / "undcmotor" / "DCmotor_prbs_open_exp.csv"
    with _warnings.catch_warnings():
        _warnings.simplefilter("default")        # the suite turns warnings into errors; a user's run does not
        assert main(["identify", str(prbs), "--time", "t:s", "--input", "u:V", "--speed", "y:deg/s",
                     "--method", "oe-friction", "--input-delay", "1"]) == 0
    err = capsys.readouterr().err
    warned = [line for line in err.splitlines() if "warning" in line.lower()]
    assert warned and all(line.startswith("motorid: warning: ") for line in warned)
    assert ".py:" not in err
