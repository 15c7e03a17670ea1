"""sim2real: robot simulation assets and reality-gap diagnosis as reproducible build outputs.

All logic lives in this package; the Snakemake rules only call into it.
"""

__all__ = ["__version__"]
__version__ = "0.1.0"
