"""Both real drivers of the rail_arm variant together, each on its emulator, through the
installed executables: every service has one owner (contract.py: the Dynamixel driver serves
set_torque/hold/reboot for the arm and gripper; the PMAC driver serves rail/set_torque,
rail/hold, rail/home) and each answers for its own hardware only."""
from __future__ import annotations

import re

import pytest

from hyperarm_description import contract
from hyperarm_description.qos import qos_for
from hyperarm_driver.dynamixel.emulator import EmulatorControl

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

NS = contract.DEFAULT_NAMESPACE
ARM_SERVICES = {f"{NS}/{s}" for s in (contract.SET_TORQUE, contract.HOLD, contract.REBOOT)}
RAIL_SERVICES = {f"{NS}/{s}" for s in (contract.RAIL_SET_TORQUE, contract.RAIL_HOLD,
                                       contract.RAIL_HOME)}


def test_dynamixel_and_pmac_drivers_own_their_services(launch, tmp_path, wait_for,
                                                       rclpy_context, executor) -> None:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import SetBool, Trigger

    link, ctl = str(tmp_path / "ttyDXL"), str(tmp_path / "ctl")
    launch("hyperarm_driver", "dxl_emulator", "--link", link, "--control", ctl)
    pmac_emu = launch("hyperarm_driver", "pmac_emulator", "--port", "0",
                      "--start-position", "2000")
    port = wait_for(lambda: re.search(r"127\.0\.0\.1:(\d+)", pmac_emu.output()), 20.0,
                    what="PMAC emulator port").group(1)
    wait_for(lambda: (tmp_path / "ctl").exists(), 20.0, what="dxl emulator control socket")
    launch("hyperarm_driver", "dynamixel_driver", params={"port": link})
    launch("hyperarm_driver", "pmac_rail_driver",
           params={"port": int(port), "variant": "rail_arm", "diagnostics_period": 0.2})

    node = rclpy.create_node("rail_arm_probe", namespace=NS, context=rclpy_context)
    diags: dict[str, dict[str, str]] = {}

    def on_diag(msg: DiagnosticArray) -> None:
        for st in msg.status:
            diags[st.name] = {kv.key: kv.value for kv in st.values}

    node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, on_diag,
                             qos_for(contract.DIAGNOSTICS))
    executor.add_node(node)

    def services_of(name: str) -> set[str]:
        try:
            return {s for s, _ in node.get_service_names_and_types_by_node(name, NS)}
        except Exception:   # noqa: BLE001 - the node is not discovered yet
            return set()

    dxl = wait_for(lambda: (s := services_of("dynamixel_driver")) >= ARM_SERVICES and s, 30.0,
                   what="the Dynamixel driver's services")
    rail = wait_for(lambda: (s := services_of("pmac_rail_driver")) >= RAIL_SERVICES and s,
                    30.0, what="the PMAC driver's services")
    assert not dxl & RAIL_SERVICES and not rail & ARM_SERVICES     # one owner per service

    def call(srv_type, name: str, data: bool | None = None):
        cli = node.create_client(srv_type, name)
        wait_for(cli.service_is_ready, 10.0, what=f"service {name}")
        req = srv_type.Request()
        if data is not None:
            req.data = data
        fut = cli.call_async(req)
        wait_for(fut.done, 5.0, what=f"answer of {name}")
        return fut.result()

    control = EmulatorControl(ctl)
    servos = lambda: control("state")["servos"]                  # noqa: E731
    rail_torque = lambda: diags.get("pmac_rail_driver: rail", {}).get("torque")  # noqa: E731
    wait_for(lambda: rail_torque() == "off", 20.0, what="rail diagnostics")

    # the rail's torque: only the PMAC motor changes, the servos stay off
    r = call(SetBool, contract.RAIL_SET_TORQUE, True)
    assert r.success and "holding position" in r.message, r.message
    wait_for(lambda: rail_torque() == "on", 3.0, what="rail torque on")
    assert all(s["torque_enable"] == 0 for s in servos().values())

    # the arm's torque: only the servos change, the rail stays on
    r = call(SetBool, contract.SET_TORQUE, True)
    assert r.success and r.message == "torque on", r.message
    assert all(s["torque_enable"] == 1 for s in servos().values())
    assert call(Trigger, contract.HOLD).success
    r = call(SetBool, contract.RAIL_SET_TORQUE, False)
    assert r.success and "killed" in r.message
    wait_for(lambda: rail_torque() == "off", 3.0, what="rail torque off")
    assert all(s["torque_enable"] == 1 for s in servos().values())   # arm untouched

    # a refusal names its own driver's reason
    r = call(Trigger, contract.RAIL_HOLD)
    assert not r.success and "rail/set_torque" in r.message, r.message
    r = call(SetBool, contract.SET_TORQUE, False)
    assert r.success and all(s["torque_enable"] == 0 for s in servos().values())
    control.close()
