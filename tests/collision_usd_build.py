"""The Panda targets the collision, USD, equivalence and Newton tests read from the suite's shared built tree
(conftest.py's ``built_tree``: `snakemake all` at fast settings, built once for the suite)."""

from __future__ import annotations

ROBOT = "panda"
TARGETS = [
    f"results/{ROBOT}/collision/report.json",
    f"results/{ROBOT}/mjcf/scene.xml",
    f"results/{ROBOT}/usd/{ROBOT}.usda",
    f"results/{ROBOT}/equivalence.json",
]
