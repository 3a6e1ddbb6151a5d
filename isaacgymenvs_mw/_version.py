"""The package's version: one place that setup.py, the package and exported policies read, importing nothing."""

__version__ = "0.1.0"
