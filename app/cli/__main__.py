"""`python -m app.cli`: the `semanticxr` command."""

import sys

from app.cli import main

sys.exit(main())
