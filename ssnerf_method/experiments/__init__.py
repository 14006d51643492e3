"""Experiments: the benchmark that writes the paper's tables."""
