"""Probes and converters that live outside the package (run from the repository root as ``python -m tools.<name>``)."""
