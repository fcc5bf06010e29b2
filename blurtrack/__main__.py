"""``python -m blurtrack``: the blurtrack CLI."""

import sys

from blurtrack.cli import main

sys.exit(main())
