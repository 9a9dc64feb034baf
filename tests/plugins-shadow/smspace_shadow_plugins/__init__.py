"""A package that registers a setup under smspace's own name `grid`, and a model whose module ends
the process at import. Not installed: tests/test_plugin_contract.py puts this folder on PYTHONPATH."""

from smspace.datagen.setups.grid import SETUPS

GRID = SETUPS[0]
