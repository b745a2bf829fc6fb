"""The progress bar: drawn on a terminal, silent otherwise."""
import io

from motorid.progress import ProgressBar


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_draws_on_a_terminal_and_ends_the_line():
    stream = _Terminal()
    with ProgressBar(4, "sweep x", stream=stream) as bar:
        for _ in range(4):
            bar.update()
    text = stream.getvalue()
    assert text.startswith("\rsweep x [") and text.endswith("\n")
    assert "4/4 points" in text and "0/4 points" in text
    assert "#" * 30 in text  # full bar at the end


def test_silent_when_not_a_terminal_or_disabled():
    plain = io.StringIO()
    with ProgressBar(3, stream=plain) as bar:
        bar.update(3)
    forced_off = _Terminal()
    with ProgressBar(3, stream=forced_off, enabled=False) as bar:
        bar.update(3)
    assert plain.getvalue() == "" and forced_off.getvalue() == ""
