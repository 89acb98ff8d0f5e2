"""Fixtures of the hyperarm_tasks tests: the fixed arm's description and kinematics."""
from __future__ import annotations

import pytest

from hyperarm_description import load_description
from hyperarm_ik.kinematics import Kinematics


@pytest.fixture(scope="module")
def desc():
    return load_description()


@pytest.fixture(scope="module")
def kin(desc):
    return Kinematics(desc)
