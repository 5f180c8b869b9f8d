"""Bytes to samples and back: line protocol, sources, recorder. Never imports widgets."""
