"""The Fast DDS profiles: the one scripts/env.sh exports (config/fastdds.xml), a default
participant profile that re-announces every 0.5 s, found where env.sh points once installed;
and the tests' one (config/fastdds_localhost.xml: the same over UDP loopback, without shared
memory). Both loaded by Fast DDS without complaint (a wrong element name would be ignored with
only a log line)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[4]
PROFILE = Path(__file__).resolve().parents[1] / "config" / "fastdds.xml"
LOCALHOST_PROFILE = PROFILE.with_name("fastdds_localhost.xml")
NS = {"d": "http://www.eprosima.com"}


def _default_participant(profile: Path) -> tuple[ET.Element, ET.Element, float]:
    """(the document's root, its one participant profile's <rtps>, its announcement period
    in s), asserting that profile is the only one and the default."""
    root = ET.parse(profile).getroot()
    parts = root.findall("d:profiles/d:participant", NS)
    assert len(parts) == 1 and parts[0].get("is_default_profile") == "true"
    rtps = parts[0].find("d:rtps", NS)
    lease = rtps.find("d:builtin/d:discovery_config/d:leaseAnnouncement", NS)
    assert lease is not None, "leaseAnnouncement missing (Fast DDS 2.x's element name)"
    period = int(lease.find("d:sec", NS).text) + int(lease.find("d:nanosec", NS).text) * 1e-9
    return root, rtps, period


@pytest.mark.core
def test_profile_is_the_default_participant_profile_announcing_every_half_second():
    _root, rtps, period = _default_participant(PROFILE)
    assert period == pytest.approx(0.5)
    assert rtps.find("d:useBuiltinTransports", NS) is None   # Fast DDS' transports, as they are


@pytest.mark.e2e
def test_env_sh_exports_the_installed_profile_and_keeps_a_users_own():
    script = ROOT / "scripts" / "env.sh"
    got = subprocess.run(["bash", "-c", f"unset FASTRTPS_DEFAULT_PROFILES_FILE; source {script}"
                          " >/dev/null && echo $FASTRTPS_DEFAULT_PROFILES_FILE"],
                         capture_output=True, text=True, timeout=60, check=True).stdout.strip()
    assert Path(got).is_file() and Path(got).resolve().read_bytes() == PROFILE.read_bytes()
    mine = subprocess.run(["bash", "-c", "export FASTRTPS_DEFAULT_PROFILES_FILE=/x/mine.xml; "
                           f"source {script} >/dev/null && echo $FASTRTPS_DEFAULT_PROFILES_FILE"],
                          capture_output=True, text=True, timeout=60, check=True).stdout.strip()
    assert mine == "/x/mine.xml"


@pytest.mark.core
def test_the_localhost_profile_announces_as_often_and_has_one_loopback_udp_transport():
    root, rtps, period = _default_participant(LOCALHOST_PROFILE)
    assert period == pytest.approx(0.5)
    assert rtps.find("d:useBuiltinTransports", NS).text == "false"
    used = [t.text for t in rtps.findall("d:userTransports/d:transport_id", NS)]
    descriptors = root.findall("d:profiles/d:transport_descriptors/d:transport_descriptor", NS)
    assert [d.find("d:transport_id", NS).text for d in descriptors] == used and len(used) == 1
    assert descriptors[0].find("d:type", NS).text == "UDPv4"
    # a 640x480 picture is 307-921 kB: Linux' default 208 kB socket buffers drop most of them
    for size in ("sendBufferSize", "receiveBufferSize"):
        assert int(descriptors[0].find(f"d:{size}", NS).text) >= 4 * 1024 * 1024, size
    assert [a.text for a in descriptors[0].findall("d:interfaceWhiteList/d:address", NS)] == [
        "127.0.0.1"]


_PROBE = """
import os, re, sys, time
import rclpy
from sensor_msgs.msg import JointState
rclpy.init()
node = rclpy.create_node("transport_probe")
pub = node.create_publisher(JointState, "transport_probe", 10)
names = [open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task")]
print("threads " + " ".join(sorted(names)), flush=True)
end = time.monotonic() + 20.0
while time.monotonic() < end and pub.get_subscription_count() == 0:
    time.sleep(0.05)
print(f"matched {pub.get_subscription_count()}", flush=True)
node.destroy_node()
rclpy.shutdown()
"""


@pytest.mark.e2e
def test_test_processes_use_loopback_udp_without_shared_memory(rclpy_context, launch_env):
    """A process started as the tests start nodes (TEST_DDS_ENV) has no shared-memory
    receive thread (Fast DDS names them dds.shm.<port>; LOCALHOST would add them) and still
    meets this test's participant over loopback."""
    import rclpy
    from sensor_msgs.msg import JointState

    node = rclpy.create_node("transport_peer", context=rclpy_context)
    try:
        node.create_subscription(JointState, "transport_probe", lambda _m: None, 10)
        # the environment the launch fixture gives a node (conftest's TEST_DDS_ENV)
        env = launch_env()
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT", env
        out = subprocess.run([sys.executable, "-c", _PROBE], env=env,
                             capture_output=True, text=True, timeout=60)
        mine = [open(f"/proc/self/task/{t}/comm").read().strip()
                for t in os.listdir("/proc/self/task")]
    finally:
        node.destroy_node()
    # this process' own participant (the in-process node tests') is on UDP alone too
    assert not [t for t in mine if t.startswith("dds.shm.") and t[8:].isdigit()], mine
    lines = dict(line.split(" ", 1) for line in out.stdout.splitlines() if " " in line)
    assert "threads" in lines, out.stdout + out.stderr
    threads = lines["threads"].split()
    assert any(t.startswith("dds.udp.") for t in threads), threads
    assert not [t for t in threads if t.startswith("dds.shm.") and t[8:].isdigit()], threads
    assert lines.get("matched") == "1", out.stdout + out.stderr


@pytest.mark.e2e
@pytest.mark.parametrize("profile", [PROFILE, LOCALHOST_PROFILE], ids=lambda p: p.name)
def test_fast_dds_loads_the_profile_without_complaint(profile):
    """A participant created under the profile: Fast DDS logs an XML parser error for an
    element it does not know, and rclpy still starts, so look for the error."""
    code = ("import rclpy; rclpy.init(); n = rclpy.create_node('profile_probe'); "
            "n.destroy_node(); rclpy.shutdown(); print('ok')")
    # domain 232: outside the suite's (100-231), where another worker's test would take the
    # probe for a stray process of its own domain
    env = dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(profile),
               RMW_IMPLEMENTATION="rmw_fastrtps_cpp", ROS_DOMAIN_ID="232")
    good = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=60)
    assert good.stdout.strip() == "ok" and "XMLPARSER" not in good.stderr, good.stderr


@pytest.mark.e2e
def test_the_stop_benchmark_measures_both_transports(ros_domain):
    """docs/benchmarks.md's figures for stopping many nodes at once come from this script: a
    small run of it on the test's domain prints one round per transport."""
    out = subprocess.run([sys.executable, "-m", "hyperarm_bringup.dds_stop_benchmark",
                          "--processes", "2", "--endpoints", "2", "--rounds", "1",
                          "--settle", "0.2"], env=dict(os.environ), capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    rounds = re.findall(r"^(shm|udp) round 1: destroy slowest ([\d.]+) s \(its CPU [\d.]+ s\), "
                        r"median ([\d.]+) s; last exit ([\d.]+) s after the signal$",
                        out.stdout, re.M)
    assert [r[0] for r in rounds] == ["shm", "udp"], out.stdout
    for _, slowest, median, last in rounds:
        assert 0 < float(median) <= float(slowest) <= float(last), out.stdout
