"""Run a blender_mrvm command inside Blender: ``blender --background -P scripts/mrvm_blender.py -- <command> ...``.

Arguments after ``--`` are the CLI's (``python -m blender_mrvm --help``). The script finds the
package next to itself (a repo checkout) or as an installed extension (``bl_ext.*.blender_mrvm``).
"""

import importlib
import os
import sys


def _cli():
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if os.path.isfile(os.path.join(here, "blender_mrvm", "__init__.py")):
        if here not in sys.path:
            sys.path.insert(0, here)
        return importlib.import_module("blender_mrvm.cli")
    import addon_utils

    for mod in addon_utils.modules():
        if mod.__name__.endswith(".blender_mrvm") or mod.__name__ == "blender_mrvm":
            return importlib.import_module(mod.__name__ + ".cli")
    raise SystemExit("blender_mrvm not found: run from a checkout or install the extension")


if __name__ == "__main__":
    _cli().main_blender()
