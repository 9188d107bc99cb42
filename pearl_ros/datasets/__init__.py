"""Readers for benchmark data sets (file I/O lives here, not in ``core``)."""
