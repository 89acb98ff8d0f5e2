"""Core: the soak's per-step time table (issue 28: where a cycle's time goes)."""
from __future__ import annotations

import pytest

from hyperarm_tasks.benchmarks.soak import step_table

pytestmark = pytest.mark.core


def test_step_table_means_maxima_and_shares_in_run_order():
    results = [
        {"time": 30.0, "steps": {"ready": 2.0, "above_source": 6.0, "insert": 10.0}},
        {"time": 34.0, "steps": {"ready": 4.0, "above_source": 8.0, "insert": 12.0,
                                 "retry_only": 1.0}},
    ]
    lines = step_table(results).splitlines()
    assert lines[0] == "time per step:"
    rows = {r.split(" | ")[0].strip("| "): r for r in lines[3:]}
    assert list(rows) == ["ready", "above_source", "insert", "retry_only"]
    assert rows["ready"] == "| ready | 3.00 | 4.00 | 9 % |"            # 3 of a mean 32 s
    assert rows["insert"] == "| insert | 11.00 | 12.00 | 34 % |"
    assert rows["retry_only"] == "| retry_only | 0.50 | 1.00 | 2 % |"   # absent = 0 s


def test_step_table_without_step_times_says_so():
    assert "n/a" in step_table([{"time": 1.0, "steps": {}}])
