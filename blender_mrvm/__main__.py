"""``python -m blender_mrvm ...``: the headless CLI (see ``cli.py``)."""

import sys

from .cli import main  # sets the OpenMP defaults before any command imports torch (threads.py)
from .threads import apply_malloc_defaults

apply_malloc_defaults()  # our own process only: not when cli.main_blender runs inside Blender

sys.exit(main())
