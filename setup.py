"""setuptools hook: everything but the package list is in pyproject.toml.

The list is here because pyproject.toml cannot say it: its find directive finds packages only
inside their own folders, and `imitation.datasets` (the bundled .mcap files, package data only)
lives in the top-level datasets/ folder ([tool.setuptools.package-dir] in pyproject.toml).
Namespace packages are found as the find directive found them (its default in pyproject.toml).
"""

from setuptools import find_namespace_packages, setup

subpackages = [f"imitation.{name}" for name in find_namespace_packages(where="imitation")]
setup(packages=["imitation", *subpackages, "imitation.datasets"])
