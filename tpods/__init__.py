"""TPODS lab-bench toolkit: shared pieces (CLI, run folders, errors)."""

__version__ = "0.1.0"
