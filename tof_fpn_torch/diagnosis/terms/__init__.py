"""One module per catalogue term of the diagnosis, each with one subclass of
:class:`~tof_fpn_torch.diagnosis.terms.base.Term`; they are registered in
:mod:`tof_fpn_torch.diagnosis.catalogue` (which says how to add one)."""
