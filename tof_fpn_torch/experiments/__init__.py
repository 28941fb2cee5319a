"""The paper's experiments, one module each, plus their shared data and report writing (offline).

May import: every layer below it (runtime, design, build, analysis, denoise, sim), NumPy,
matplotlib (through :mod:`tof_fpn_torch.plotting`). Nothing imports it but the CLI and the scripts.

- :mod:`.common`: the synthetic data of Table I / Fig. 9, the NLM settings, shared checks.
- :mod:`.table1`: Table I (and the NLM tuning run).
- :mod:`.fig9`: Fig. 9.
- :mod:`.table2`: Table II and a Fig. 10-like figure (denoisers on simulated low-sensing data).
- :mod:`.demo`: the end-to-end demo.
- :mod:`.report`: CSV / JSON / Markdown / PNG writing.
"""

from .common import CASE_LABELS, CASES, NLMSettings, SyntheticData, make_synthetic_data
from .demo import DemoResult, run_demo
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
    "DemoResult",
    "NLMSettings",
    "SyntheticData",
    "Table2Setup",
    "make_synthetic_data",
    "run_demo",
    "run_fig9",
    "run_table1",
    "run_table2",
    "tune_nlm",
    "write_fig9",
    "write_table1",
    "write_table2",
]
