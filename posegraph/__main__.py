"""``python -m posegraph …``: the ``posegraph`` command (:mod:`posegraph.cli`)."""

import sys

from posegraph.cli import main

sys.exit(main())
