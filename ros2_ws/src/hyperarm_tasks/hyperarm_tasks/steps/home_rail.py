"""``home_rail``: start the rail's home search and wait until it reports homed (nothing to
do, logged, on the fixed-base arm or when the rail is homed already).

    - name: home
      type: home_rail
      timeout: 30 s
"""
from __future__ import annotations

from dataclasses import dataclass

from ..errors import StepFailed
from . import BuildContext, Step, StepType, register


@dataclass(frozen=True)
class HomeRail(Step):
    pass


def build(raw: dict, ctx: BuildContext, index: int) -> HomeRail:
    return HomeRail(**ctx.common(raw, index, 30.0))


def run(step: HomeRail, runner) -> None:
    robot = runner.robot
    if runner.desc.rail is None:
        robot.log("info", f"{step.name}: no rail on this variant, nothing to home")
        return
    if robot.rail_homed():
        robot.log("info", f"{step.name}: the rail is homed already")
        return
    reason = robot.home_rail()
    if reason:
        raise StepFailed("driver", f"rail homing refused: {reason}")
    t0 = robot.now()
    while not robot.rail_homed():
        if robot.now() - t0 > step.timeout:
            raise StepFailed("timeout", f"the rail did not report homed in {step.timeout:g} s")
        runner.feedback("homing", min((robot.now() - t0) / step.timeout, 0.99))
        runner.tick()


register(StepType("home_rail", {}, (), build, run, "home the rail"))
