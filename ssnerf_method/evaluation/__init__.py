"""Metrics for every property (used by the model's `ns-eval` hook, the demo and the benchmarks)."""
