"""The Fast DDS profile scripts/env.sh exports (config/fastdds.xml): a default participant
profile that re-announces every 0.5 s, found where env.sh points once installed, and
loaded by Fast DDS (a wrong element name would be ignored with only a log line)."""
from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[4]
PROFILE = Path(__file__).resolve().parents[1] / "config" / "fastdds.xml"
NS = {"d": "http://www.eprosima.com"}


@pytest.mark.core
def test_profile_is_the_default_participant_profile_announcing_every_half_second():
    root = ET.parse(PROFILE).getroot()
    parts = root.findall("d:profiles/d:participant", NS)
    assert len(parts) == 1 and parts[0].get("is_default_profile") == "true"
    lease = parts[0].find("d:rtps/d:builtin/d:discovery_config/d:leaseAnnouncement", NS)
    assert lease is not None, "leaseAnnouncement missing (Fast DDS 2.x's element name)"
    period = int(lease.find("d:sec", NS).text) + int(lease.find("d:nanosec", NS).text) * 1e-9
    assert period == pytest.approx(0.5)


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


@pytest.mark.e2e
def test_fast_dds_loads_the_profile_without_complaint():
    """A participant created under the profile: Fast DDS logs an XML parser error for an
    element it does not know, and rclpy still starts, so look for the error."""
    code = ("import rclpy; rclpy.init(); n = rclpy.create_node('profile_probe'); "
            "n.destroy_node(); rclpy.shutdown(); print('ok')")
    env = dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(PROFILE),
               RMW_IMPLEMENTATION="rmw_fastrtps_cpp", ROS_DOMAIN_ID="231")
    good = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, timeout=60)
    assert good.stdout.strip() == "ok" and "XMLPARSER" not in good.stderr, good.stderr
