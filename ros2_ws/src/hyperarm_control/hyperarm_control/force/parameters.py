"""The hybrid_force node's parameters as one table (no ROS): defaults, descriptions, ranges.

The node declares them from this table; docs/force.md lists them (a test checks that the
two agree); :func:`build` turns their values into the cores' validated configurations.
"""
from __future__ import annotations

from dataclasses import fields
from typing import Any, Mapping

from hyperarm_description.params import OneOf, ParamSpec, Range

from .controller import ControllerConfig
from .errors import ForceConfigError
from .law import OUTPUTS, LawConfig
from .wrench import EstimatorConfig

__all__ = ["PARAMETERS", "DYNAMIC", "build", "TRIGGERS"]

TRIGGERS = ("joint_states", "timer")
#: hyperarm_description.ros_main.EXECUTORS (that module imports rclpy; a node test checks)
EXECUTORS = ("events", "single")
_L, _E, _C = LawConfig(), EstimatorConfig(), ControllerConfig()

# name -> (default, description, check): hyperarm_description.params' table format (also
# the node's --help). Lists and bools have no check (their lengths: the cores validate).
PARAMETERS: ParamSpec = {
    "output": (_C.output, "'position' (pseudo-goal + current limit, current-based position) or "
               "'torque' (effort-only joint_command, current mode)", OneOf(OUTPUTS)),
    "trigger": ("joint_states", "compute on each joint_states message ('joint_states') or on "
                "a timer at 'rate' ('timer')", OneOf(TRIGGERS)),
    "executor": ("events", "rclpy executor of the node: 'events' (rclpy.experimental."
                 "EventsExecutor, the lower latency) or 'single' (SingleThreadedExecutor)",
                 OneOf(EXECUTORS)),
    "rate": (100.0, "Hz, control rate with trigger 'timer'", Range(1.0, 1000.0)),
    "stale_timeout": (_C.stale_timeout, "s without joint_states before going passive",
                      Range(0.01, 10.0)),
    "state_max_age": (_C.state_max_age, "s, a joint state stamped longer ago (or before the "
                      "newest one used from its driver) is dropped", Range(0.01, 10.0)),
    "goal_max_age": (_C.goal_max_age, "s, a hybrid goal stamped longer ago (or before the "
                     "newest one used) is ignored", Range(0.01, 60.0)),
    "switch_gap": (_C.switch_gap, "s the servos' torque is off when the 'torque' output's "
                   "first command switches them into current mode (its lost impulse is added "
                   "back over the first switch_spread commands; 0 = not)", Range(0.0, 0.05)),
    "switch_spread": (_C.switch_spread, "commands (1-10) over which the 'torque' output adds "
                      "back the impulse lost in the switch gap (more: robust to a first "
                      "command overtaken by the next, a larger excursion when none is)",
                      Range(1, 10)),
    "limit_guard": (_C.limit_guard, "rad from a joint limit at which the node goes passive",
                    Range(0.0, 0.5)),
    "default_stiffness": (list(_C.default_stiffness), "K [N/m x3, N·m/rad x3] of the hold "
                          "goal at enable, and of position axes a goal leaves at 0", None),
    "position_stiffness": (list(_L.position_stiffness), "least K of position-controlled axes "
                           "in the 'position' output [N/m x3, N·m/rad x3]", None),
    "damping": (list(_L.damping), "Cartesian damping on the tool twist [N·s/m x3, "
                "N·m·s/rad x3]", None),
    "joint_damping": (_L.joint_damping, "N·m·s/rad on every arm joint", Range(0.0, 10.0)),
    "posture": ([0.0] * 9, "rad, preferred arm posture of the null-space term (joint1..9)",
                None),
    "posture_stiffness": (_L.posture_stiffness, "N·m/rad of the null-space posture spring",
                          Range(0.0, 100.0)),
    "posture_speed": (_L.posture_speed, "rad/s at which the posture spring's reference moves "
                      "from the posture at enable to 'posture'", Range(1e-3, 10.0)),
    "limit_margin": (_L.limit_margin, "rad from a limit where the null-space push starts",
                     Range(0.0, 1.0)),
    "limit_stiffness": (_L.limit_stiffness, "N·m/rad scale of the push away from the "
                        "limits (a barrier: k_l m (m - d) / max(d, m/4) at d from a limit)",
                        Range(0.0, 1000.0)),
    "torque_margin": (_L.torque_margin, "fraction of each servo's stall torque the node may "
                      "command", Range(0.05, 1.0)),
    "torque_rate": (_L.torque_rate, "N·m/s, largest change of a joint torque", Range(1e-3, 1e6)),
    "max_force": (_L.max_force, "N, Cartesian force limit (wrench scaled, direction kept)",
                  Range(0.0, 1000.0)),
    "max_moment": (_L.max_moment, "N·m, Cartesian moment limit", Range(0.0, 100.0)),
    "max_linear_stiffness": (_L.max_linear_stiffness, "N/m, goals with more are refused",
                             Range(0.0, 1e6)),
    "max_angular_stiffness": (_L.max_angular_stiffness, "N·m/rad, goals with more are refused",
                              Range(0.0, 1e4)),
    "workspace_margin": (_L.workspace_margin, "m a goal may lie beyond the reach bound",
                         Range(0.0, 10.0)),
    "max_speed": (_L.max_speed, "m/s at which the reference follows a goal", Range(1e-3, 2.0)),
    "max_angular_speed": (_L.max_angular_speed, "rad/s, same for orientation", Range(1e-3, 10.0)),
    "singular_damping": (_L.singular_damping, "m, damping of the law's pseudo-inverses",
                         Range(1e-6, 1.0)),
    "servo_stiffness": (_L.servo_stiffness, "N·m/rad of the servos' position loop "
                        "('position' output)", Range(0.1, 1e5)),
    "servo_holds_gravity": (_L.servo_holds_gravity, "the servos' integral action holds "
                            "gravity in position mode (else q_cmd adds g/k_s)", None),
    "effort_headroom": (_L.effort_headroom, "N·m above |g| + |k_s (q_cmd - q)| for the 'position' output's "
                        "current limit", Range(0.0, 10.0)),
    "position_filter": (_L.position_filter, "per-cycle gain of the pseudo-goal on position "
                        "axes", Range(1e-3, 1.0)),
    "force_filter": (_L.force_filter, "per-cycle gain of the pseudo-goal on force axes",
                     Range(1e-3, 1.0)),
    "force_rate": (_L.force_rate, "N/s, fastest change of the force axes' wrench ('position' "
                   "output; moments x max_moment/max_force): presses build and release at "
                   "most this fast", Range(0.1, 1e4)),
    "compliance_stiffness": (_L.compliance_stiffness, "N·m/rad per joint in compliance mode",
                             Range(0.0, 100.0)),
    "transition_time": (_L.transition_time, "s over which whole-arm compliance fades in or "
                        "out", Range(0.0, 10.0)),
    "compliance_effort": (_L.compliance_effort, "N·m above gravity per joint in compliance "
                          "mode", Range(0.0, 100.0)),
    "payload_mass": (0.0, "kg held at tool0 (gravity compensated; may be set at run time)",
                     Range(0.0, 10.0)),
    "payload_com": ([0.0, 0.0, 0.0], "m, the payload's centre of mass in tool0 (run time)",
                    None),
    "calibration_file": ("", "torque calibration YAML from hybrid_force_calibrate ('' = none)",
                         None),
    "wrench_filter": (_E.filter, "per-cycle gain of the wrench estimate's low-pass",
                      Range(1e-4, 1.0)),
    "effort_noise": (_E.effort_noise, "N·m, std of a measured effort (the covariance)",
                     Range(0.0, 10.0)),
    "friction_noise": (_E.friction_noise, "N·m, std of the friction left in a measured "
                       "effort after calibration (the covariance; not filtered)",
                       Range(0.0, 10.0)),
    "diagnostics_period": (1.0, "s between /diagnostics messages", Range(0.1, 10.0)),
}
DYNAMIC = ("payload_mass", "payload_com")
_RENAMED = {"wrench_filter": "filter"}


def build(values: Mapping[str, Any]) -> tuple[LawConfig, EstimatorConfig, ControllerConfig]:
    """The cores' configurations from parameter values; raises ForceConfigError."""
    def pick(cls, skip=()):
        names = {f.name for f in fields(cls)}
        out = {}
        for key, value in values.items():
            name = _RENAMED.get(key, key)
            if name in names and name not in skip:
                out[name] = tuple(value) if isinstance(value, list) else value
        return out

    try:
        law = LawConfig(**pick(LawConfig))
        est = EstimatorConfig(**pick(EstimatorConfig, skip=("singular_damping",)))
        ctl = ControllerConfig(**pick(ControllerConfig))
    except TypeError as exc:
        raise ForceConfigError(str(exc)) from exc
    return law, est, ctl
