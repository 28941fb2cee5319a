"""The paper's experiments (not installed: the lab beside the package), one module each, plus
their report writing. Run them with ``python benchmarks/reproduce.py``.

Imports the package (:mod:`tof_fpn_torch`; the synthetic data of Table I / Fig. 9 and the NLM
settings are :mod:`tof_fpn_torch.paper_data`, shared with ``tof-fpn demo``), NumPy and matplotlib.

- :mod:`.table1`: Table I (and the NLM tuning run).
- :mod:`.fig9`: Fig. 9.
- :mod:`.table2`: Table II and a Fig. 10-like figure (denoisers on simulated low-sensing data).
- :mod:`.report`: CSV / JSON / Markdown / PNG writing.
"""

from tof_fpn_torch.paper_data import (
    CASE_LABELS,
    CASES,
    NLMSettings,
    SyntheticData,
    make_synthetic_data,
)

from .fig9 import QUICK_EVEN_ORDERS, QUICK_ODD_ORDERS, QUICK_RHOS, run_fig9, write_fig9
from .table1 import run_table1, tune_nlm, write_table1
from .table2 import PAPER_METHODS, Table2Setup, run_table2, write_table2

__all__ = [
    "CASES",
    "CASE_LABELS",
    "PAPER_METHODS",
    "QUICK_EVEN_ORDERS",
    "QUICK_ODD_ORDERS",
    "QUICK_RHOS",
    "NLMSettings",
    "SyntheticData",
    "Table2Setup",
    "make_synthetic_data",
    "run_fig9",
    "run_table1",
    "run_table2",
    "tune_nlm",
    "write_fig9",
    "write_table1",
    "write_table2",
]
