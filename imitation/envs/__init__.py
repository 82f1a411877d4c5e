"""Environment construction and the project's own environments."""
