"""``motorid identify``: --json uncertainty, --validate, --report, --input-delay, --fix-bias."""
import json

import pytest

from motorid.cli import main


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("runs")
    train, test = d / "train.csv", d / "test.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--sine", "10,200", "--duration", "5",
                 "--jitter", "0.1", "--drop-rate", "0.01", "--seed", "1", "--out", str(train)]) == 0
    assert main(["simulate", "--a", "25", "--b", "3", "--multisine", "7,90,0;31,90,1", "--duration", "5",
                 "--seed", "2", "--out", str(test)]) == 0
    return train, test


def test_json_carries_standard_errors_intervals_and_validation(runs, capsys, tmp_path):
    train, test = runs
    png = tmp_path / "report.png"
    capsys.readouterr()
    assert main(["identify", str(train), "--validate", str(test), "--report", str(png), "--json"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)             # stdout is the JSON document alone
    assert data["method"] == "oe"
    # quantisation-only errors: z-scores over 104 benchmark cases had std 1.0-1.2, so allow 4 standard errors
    assert abs(data["a"] - 25.0) < 4 * data["a_stderr"] and abs(data["b"] - 3.0) < 4 * data["b_stderr"]
    lo, hi = data["a_ci95"]
    assert lo < data["a"] < hi and hi - lo == pytest.approx(2 * 1.959964 * data["a_stderr"], rel=1e-6)
    assert data["validation_fit_percent"] > 99.0 and "whiteness_p" in data
    assert "95 % CI" in captured.err and "validation" in captured.err   # the human text is on stderr
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_friction_flags_reach_the_estimator(runs, capsys):
    _, test = runs  # the run without dropped samples: one segment keeps the finite differences cheap
    capsys.readouterr()
    assert main(["identify", str(test), "--method", "oe-friction", "--fix-bias", "--input-delay", "0", "--json"]) == 0
    data = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert data["bias"] == 0.0 and "friction_stderr" in data and "bias_stderr" not in data


@pytest.mark.parametrize("argv, message", [
    (["--method", "zoh-ls", "--input-delay", "2"],
     "--input-delay is not supported by method 'zoh-ls': it takes no options"),
    (["--method", "oe", "--fix-bias"],
     "--fix-bias is not supported by method 'oe': its options are input_delay, fit_bias, jac, covariance"),
], ids=["input-delay-zoh-ls", "fix-bias-oe"])
def test_unsupported_flags_are_user_errors(runs, capsys, argv, message):
    train, _ = runs
    assert main(["identify", str(train), *argv]) == 2
    assert message in capsys.readouterr().err


def test_bad_delay_value_is_refused(runs, capsys):
    with pytest.raises(SystemExit):
        main(["identify", str(runs[0]), "--input-delay", "soon"])
    assert "--input-delay must be 'auto' or an integer >= 0 (samples), got 'soon'" in capsys.readouterr().err


def test_plain_identify_finds_a_two_sample_delay_and_says_so(tmp_path, capsys):
    run = tmp_path / "delayed.csv"
    assert main(["simulate", "--a", "25", "--b", "3", "--multisine", "7,90,0;31,90,1", "--duration", "5",
                 "--input-delay", "2", "--seed", "3", "--out", str(run)]) == 0
    capsys.readouterr()
    assert main(["identify", str(run), "--json"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)        # --json: stdout is one JSON document, the text goes to stderr
    # with delay 0 the fit was off by -22 %; with the delay found, quantisation-only errors: 4 standard errors
    assert data["input_delay"] == 2 and "model       linear, input delay 2 samples (oe), chosen" in captured.err
    assert abs(data["a"] - 25.0) < 4 * data["a_stderr"] and abs(data["b"] - 3.0) < 4 * data["b_stderr"]
