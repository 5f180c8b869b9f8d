"""Whole logs and sessions at once: `filter` and `evaluate` (filtering, also the estimates' CSV),
the instant re-filter of Tune's A/B comparison (refilter), exports (export, matfile) and the one
rule for output files (outputs)."""
