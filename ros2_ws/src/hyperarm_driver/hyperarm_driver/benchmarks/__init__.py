"""Benchmark scripts (console scripts dxl_benchmark, pmac_benchmark, mock_benchmark)."""
