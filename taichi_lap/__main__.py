"""``python -m taichi_lap`` is the ``taichi-lap`` command."""

import sys

from taichi_lap.cli import main

sys.exit(main())
