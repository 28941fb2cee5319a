"""Where the real ToF captures are: ``tests/data/real`` in this repository (README there: the
files, their sources and licences). The tests name the same folder in ``tests/conftest.py``."""

from pathlib import Path

REAL_DATA_DIR = Path(__file__).resolve().parents[1] / "tests" / "data" / "real"
