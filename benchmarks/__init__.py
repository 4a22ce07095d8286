"""Benchmarks: ours vs peers side by side, printed as markdown tables."""
