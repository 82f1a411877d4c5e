"""Converters: each turns one kind of recording into Episodes with spaces (see job.py)."""
