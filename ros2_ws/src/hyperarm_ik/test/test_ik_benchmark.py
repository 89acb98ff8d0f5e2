"""The documented benchmark command keeps working (a tiny run; figures are not asserted)."""
from __future__ import annotations

import numpy as np
import pytest

from hyperarm_ik.benchmark import ik_benchmark as bench
from hyperarm_ik.kinematics import Kinematics

pytestmark = pytest.mark.core


def test_benchmark_runs_and_prints_its_table(capsys, tmp_path):
    doc = tmp_path / "ik.md"
    doc.write_text("intro\n<!-- ik_benchmark:begin -->\nOLD-BLOCK\n<!-- ik_benchmark:end -->\nend\n")
    bench.main(["--count", "6", "--slow-count", "1", "--ikpy-count", "1",
                "--unreachable-count", "3", "--sensitivity-count", "2",
                "--skip", "tight", "rail", "service", "--markdown", str(doc)])
    out = capsys.readouterr().out
    assert "| random | default | 6 |" in out
    assert "| figure8 | default | 6 |" in out
    assert "| figure8_wide | pinv (re-seeded from failures) | 6 |" in out
    assert "| near_limit | default | 6 |" in out
    assert "| default (service default timeout 0.1 s) | 3 |" in out
    assert "within 1.2x: 3/3" in out  # every unreachable target's answer is proven close
    assert "| K_w = 1000, full steps (no halving) |" in out
    text = doc.read_text()
    assert "OLD-BLOCK" not in text and "| random | default | 6 |" in text
    assert text.startswith("intro\n") and text.endswith("end\n")


def test_evaluation_judges_by_our_fk():
    kin = Kinematics()
    q = np.full(9, 0.2)
    t = kin.forward(q)
    run = bench.Run("x", "y")
    assert bench.evaluate(kin, run, q, t[:3, 3], t[:3, :3], (1e-9, 1e-9))
    bad = q.copy()
    bad[3] = 2.7  # beyond 150 deg
    assert not bench.evaluate(kin, run, bad, kin.forward(bad)[:3, 3], t[:3, :3], (1e-3, 1e-3))
    assert not bench.evaluate(kin, run, None, t[:3, 3], t[:3, :3], (1e-3, 1e-3))
    assert (run.n, run.ok_paper, run.violations, run.no_answer) == (3, 1, 1, 1)


def test_tracking_is_reseeded_from_the_last_success_only():
    kin = Kinematics()
    seeds = []
    q_good = np.full(9, 0.1)
    answers = iter([q_good, np.full(9, 2.9), q_good])  # second: outside the limits

    def solve(p, r, seed):
        seeds.append(np.array(seed))
        return next(answers)
    t = kin.forward(q_good)
    targets = [(t[:3, 3], t[:3, :3])] * 3
    bench.run_track(kin, bench.Adapter("fake", solve), "x", targets, (1e-3, 1e-3))
    np.testing.assert_array_equal(seeds[2], q_good)  # not the failed answer
    seeds.clear()
    answers = iter([q_good, np.full(9, 2.9), q_good])
    bench.run_track(kin, bench.Adapter("fake", solve), "x", targets, (1e-3, 1e-3),
                    reseed="returned")
    np.testing.assert_array_equal(seeds[2], np.full(9, 2.9))


ALL_BUT_FIGURE8 = ["random", "tight", "figure8_wide", "near_limit", "unreachable", "impossible",
                   "collision", "sensitivity", "rail", "service"]


def test_figure8_option_places_the_pattern_and_says_so(capsys):
    """``--figure8 CX CY CZ HALF_WIDTH HALF_HEIGHT`` runs the figure8 set on that figure-8
    (Table II's pattern row depends on where it is, docs/benchmarks/ik.md) and notes it."""
    bench.main(["--count", "4", "--figure8", "0.2", "0", "0.35", "0.2", "0.1",
                "--service-count", "0", "--skip", *ALL_BUT_FIGURE8])
    out = capsys.readouterr().out
    assert "| figure8 | pinv | 4 |" in out
    assert "figure8 set on centre (0.2, 0.0, 0.35) m, half width 0.2 m" in out


@pytest.mark.parametrize("values, says", [
    (["0.2", "0", "0.35", "-1", "0.1"], "half_width must be > 0"),
    (["0.2", "0", "nan", "0.2", "0.1"], "center must be 3 finite numbers"),
])
def test_a_bad_figure8_is_a_usage_error_naming_it(capsys, values, says):
    with pytest.raises(SystemExit) as exc:
        bench.main(["--figure8", *values, "--skip", *ALL_BUT_FIGURE8])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--figure8:" in err and says in err, err
