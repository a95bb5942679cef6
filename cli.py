"""``python cli.py …`` from a checkout: the ``posegraph`` command, implemented in :mod:`posegraph.cli`."""

import sys

from posegraph.cli import main

if __name__ == "__main__":
    sys.exit(main())
