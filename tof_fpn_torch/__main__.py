"""``python -m tof_fpn_torch``: the ``tof-fpn`` command line."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
