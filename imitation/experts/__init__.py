"""Experts that label states with actions: scripted controllers, saved policies."""
