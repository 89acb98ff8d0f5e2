"""IK benchmark (console script ik_benchmark)."""
