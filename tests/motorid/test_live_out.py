"""``motorid live`` without ``--out``: a timestamped recording in the current folder, named on stderr."""
import re

from motorid.cli import main
from motorid.commands.live import default_out_path
from motorsim.reading import read_recording


def test_live_without_out_writes_a_timestamped_file_named_on_stderr(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["live", "--port", "fake://?a=25&b=3&speed=0", "--duration", "1", "--quiet"]) == 0
    err = capsys.readouterr().err
    name = re.search(r"recording to (live-\d{8}-\d{6}(-\d+)?\.csv)", err).group(1)
    assert [p.name for p in tmp_path.iterdir()] == [name]
    assert read_recording(tmp_path / name).metadata["complete"] == "true"


def test_default_out_path_never_reuses_a_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    first = default_out_path(now=0.0)
    (tmp_path / first).write_text("")
    second = default_out_path(now=0.0)
    assert second != first and second.endswith("-2.csv") and second.startswith(first[:-4])
