"""``python -m blender_mrvm ...``: the headless CLI (see ``cli.py``)."""

import sys

from .cli import main  # sets the OpenMP defaults before any command imports torch (threads.py)

sys.exit(main())
