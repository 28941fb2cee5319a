"""``python -m tof_fpn_torch``: the ``tof-fpn`` command line."""

import sys

from .cli import main

sys.exit(main())
