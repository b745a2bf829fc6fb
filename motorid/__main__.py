"""``python -m motorid``: the ``motorid`` command line."""
import os
import signal
import sys


def _ended_early(signum, frame):       # pragma: no cover - a signal while the command line still loads
    os._exit(128 + signum)


# until main() installs its own handlers, a signal ends the process quietly with 128 + its number (on a
# loaded machine importing the command line takes a noticeable moment)
for _signum in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_signum, _ended_early)

from motorid.cli import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
