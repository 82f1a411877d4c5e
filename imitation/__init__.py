"""Imitation learning toolkit with MCAP demonstration datasets."""

__version__ = "0.1.0"
