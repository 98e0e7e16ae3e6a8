"""``python -m stereograph``: the ``stereograph`` command."""

import sys

from stereograph.app.cli import main

sys.exit(main())
