"""`python -m companion`: see companion.app.cli."""

import sys

from companion.app.cli import main

sys.exit(main())
