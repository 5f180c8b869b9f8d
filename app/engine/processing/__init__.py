"""Bytes -> estimates, the processing the live engine, a replay's index, exports, `filter` and
Tune's re-runs share: the pipeline (parser, time orderer, runner), the estimator runner and its
rows, the configuration over time, checkpoints of the whole state, the same-instant comparison
with the phone's estimate, the innovations probe and the stream's health."""
