"""Diagnostics of the mock, as plain data (no ROS): the node turns them into messages.

The keys mirror the real drivers' (docs/dynamixel.md, docs/pmac.md) so that monitoring
tools see the same fields: one status per servo, one for the "bus", one for the rail (rail
variant) and one for the simulated work cell.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .joint_sim import ControlMode, JointSim

__all__ = ["DiagStatus", "BusStats", "mock_diagnostics"]

OK, WARN, ERROR = "OK", "WARN", "ERROR"


@dataclass(frozen=True)
class DiagStatus:
    name: str
    hardware_id: str
    level: str
    message: str
    values: dict[str, str] = field(default_factory=dict)


@dataclass
class BusStats:
    """Cycle statistics the node keeps (wall-clock s per cycle) since the last report."""

    cycles: int = 0
    rejected_setpoints: int = 0
    last_rejection: str = ""      # why the last rail setpoint was refused (PMAC driver's key)
    cycle_times: list[float] = field(default_factory=list)


def _mode_name(sim: JointSim, i: int) -> str:
    mode = sim.mode[i]
    return sim._hold_mode(i).value if mode is ControlMode.OFF else mode.value


def mock_diagnostics(sim: JointSim, stats: BusStats, period: float, sim_speed: float,
                     node: str = "mock_driver") -> list[DiagStatus]:
    """Statuses for one /diagnostics message; clears ``stats.cycle_times``."""
    out: list[DiagStatus] = []
    servos = {j.name: j.servo for j in sim.desc.joints}
    servos[sim.desc.gripper.name] = sim.desc.gripper.servo
    for i, name in enumerate(sim.names):
        if name == sim.rail:
            continue
        servo = servos[name]
        err = sim.errors.get(name)
        out.append(DiagStatus(
            name=f"{node}: {name}", hardware_id=f"dxl-{servo.id}",
            level=ERROR if err else OK, message=f"hardware error: {err}" if err else "OK",
            values={"id": str(servo.id), "model": servo.model, "mode": _mode_name(sim, i),
                    "torque": "off" if sim.mode[i] is ControlMode.OFF else "on",
                    "temperature_C": "30", "voltage_V": "12.0",
                    "hardware_error": err or "none",
                    "hardware_error_bits": str(32 if err == "overload" else (1 if err else 0))}))
    times = stats.cycle_times
    mean_ms = f"{1e3 * sum(times) / len(times):.3f}" if times else "n/a"
    out.append(DiagStatus(
        name=f"{node}: bus", hardware_id="mock", level=OK, message="OK (simulated)",
        values={"port": "mock", "baud": "0", "connected": "True", "sync_read": "fast",
                "cycles": str(stats.cycles), "cycle_time_ms": mean_ms,
                "rate_hz": f"{len(times) / period:.1f}", "comm_errors": "0",
                "error_rate": "0.0000", "reconnects": "0", "last_error": ""}))
    stats.cycle_times = []
    if sim.rail is not None:
        i = sim.names.index(sim.rail)
        enabled = sim.mode[i] is not ControlMode.OFF
        level, message = OK, "OK"
        if not sim.homed:
            level, message = WARN, "not homed"
        elif not enabled:
            level, message = WARN, "killed"
        out.append(DiagStatus(
            name=f"{node}: rail", hardware_id="mock-pmac", level=level, message=message,
            values={"link": "up", "endpoint": "mock", "motor": str(sim.desc.rail.pmac_motor),
                    # the PMAC driver's: torque as the driver set it; faults latched until
                    # rail/set_torque true (the mock's rail has none); the on-card watchdog
                    # (nothing to lose on the mock: always "on", as the driver's default)
                    "torque": "on" if enabled else "off",
                    "latched_faults": sim.errors.get(sim.rail, "none"),
                    "watchdog": "on", "watchdog_trips": "0",
                    "position_m": f"{sim.position[i]:.6f}",
                    "velocity_mps": f"{sim.velocity[i]:.6f}",
                    "following_error_m": f"{sim.goal[i] - sim.position[i]:.6f}"
                    if enabled else "0.000000",
                    "homed": str(sim.homed).lower(), "amp_enabled": str(enabled).lower(),
                    "in_position": str(abs(sim.goal[i] - sim.position[i]) < 1e-4).lower(),
                    "neg_limit": "false", "pos_limit": "false", "amp_fault": "false",
                    "fatal_following_error": "false", "warning_following_error": "false",
                    "status_word": "mock", "round_trip_ms": "0.0", "reconnects": "0",
                    "rejected_setpoints": str(stats.rejected_setpoints),
                    "last_rejection": stats.last_rejection or "none", "last_error": ""}))
    if sim.host is not None:   # the scripted host motion (host_motion.py)
        hs = sim.host.status()
        out.append(DiagStatus(
            name=f"{node}: host_motion", hardware_id="mock",
            level=WARN if hs["last_abort"] else OK,
            message=f"{hs['name']}: {hs['phase']}" + (f" ({hs['last_abort']})"
                                                      if hs["last_abort"] else ""),
            values=hs))
    w = sim.world
    f = sim.contact_force
    out.append(DiagStatus(
        name=f"{node}: work_cell", hardware_id="mock", level=OK,
        message=f"block {w.state.value}" + (f" ({w.peg})" if w.peg else ""),
        values={"sim_time_s": f"{sim.time:.3f}", "sim_speed": f"{sim_speed:g}",
                "block_state": w.state.value, "block_peg": w.peg or "",
                "contact_force_N": f"{f[0]:.3f} {f[1]:.3f} {f[2]:.3f}",
                "link_contacts": ", ".join(
                    f"{link}:{pole}:{float((force @ force) ** 0.5):.2f}N"
                    for link, pole, _, force in sim.link_contacts)}))
    return out
