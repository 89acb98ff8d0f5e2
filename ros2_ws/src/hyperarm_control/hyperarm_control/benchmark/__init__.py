"""Benchmarks of the controllers (scripts that print their figures; docs/benchmarks.md)."""
