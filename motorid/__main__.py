"""``python -m motorid``: the ``motorid`` command line."""
import sys

from motorid.cli import main

if __name__ == "__main__":
    sys.exit(main())
