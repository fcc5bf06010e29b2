"""``python -m gamd`` runs the gamd command line."""

import sys

from gamd.cli import main

if __name__ == "__main__":
    sys.exit(main())
