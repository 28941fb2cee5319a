"""Sub-commands of the ``tof-fpn`` CLI (see :mod:`tof_fpn_torch.cli`)."""
