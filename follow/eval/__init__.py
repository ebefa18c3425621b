"""Metrics, dataset readers, evaluations and benchmarks."""
