"""Evaluation of policies and recovered rewards."""
