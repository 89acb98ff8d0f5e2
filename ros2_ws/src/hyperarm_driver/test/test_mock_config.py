"""Core tier: the mock's work-cell YAML (packaged default and validation errors)."""
from __future__ import annotations

import copy

import pytest
import yaml

from hyperarm_driver.mock.config import (MockConfigError, default_workcell_path,
                                         load_mock_config, parse_mock_config)

pytestmark = pytest.mark.core


@pytest.fixture(scope="module")
def raw() -> dict:
    return yaml.safe_load(default_workcell_path().read_text())


def test_default_mirrors_the_papers_demonstration():
    cfg = load_mock_config()
    assert [p.name for p in cfg.world.pegs] == ["source", "destination"]
    assert cfg.world.block.start == "source"
    assert cfg.world.clearance("destination") == pytest.approx(0.002)   # 2 mm radial
    assert cfg.world.clearance("source") == pytest.approx(0.002)
    assert cfg.imperfections.repeatability > 0.0    # the arm cannot just drop the block on


@pytest.mark.parametrize("path, value, message", [
    (("servo", "stiffness"), -1.0, "servo.stiffness: must be > 0"),
    (("servo", "bogus"), 1.0, "servo: unknown key(s) ['bogus']"),
    (("imperfections", "position_noise"), float("nan"),
     "imperfections.position_noise: must be finite"),
    (("imperfections", "seed"), -3, "imperfections.seed: must be a non-negative integer"),
    (("world", "pegs", "destination", "radius"), 0.010, "world.pegs.destination.radius"),
    (("world", "pegs", "source", "height"), 0.02, "must exceed the block's height"),
    (("world", "block", "start"), "nowhere", "world.block.start: 'nowhere' is not a peg"),
    (("world", "block", "hole_radius"), 0.03, "does not fit in a block"),
    (("world", "pegs", "destination", "xy"), [0.35, 0.13], "too close"),
    (("world", "table_height"), "low", "world.table_height: expected a number"),
    (("camera", "rate"), 0.0, "camera.rate: must be > 0"),
])
def test_bad_values_name_the_field(raw, path, value, message):
    data = copy.deepcopy(raw)
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(MockConfigError) as err:
        parse_mock_config(data)
    assert message in str(err.value)


def test_missing_world_and_unreadable_file(raw, tmp_path):
    data = copy.deepcopy(raw)
    del data["world"]
    with pytest.raises(MockConfigError, match="world: missing"):
        parse_mock_config(data)
    with pytest.raises(MockConfigError, match="cannot read work-cell file"):
        load_mock_config(tmp_path / "none.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("world: [unclosed")
    with pytest.raises(MockConfigError, match="not valid YAML"):
        load_mock_config(bad)
