"""E2E: the installed ``viewer`` in a real browser (headless Chromium through Selenium).

The viewer runs as its own process on a free port; the test publishes joint_states itself
(in-process). Chromium loads the page and the test checks screenshots: the robot is drawn
(enough pixels of its dark servo colour, where a blank or broken page has none), and the
picture changes when the joints move. ``HYPERARM_VIEWER_SCREENSHOT=path.png`` keeps the
last screenshot (docs/viewer.png is the same kind of capture, of the viewer on the mock).
"""
from __future__ import annotations

import io
import os
import re
import shutil
import threading

import numpy as np
import pytest

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
ARM = [f"joint{i}" for i in range(1, 10)]
POSE_A = [0.0, 0.5, 0.0, 0.5, 0.0, 0.5, 0.0, 0.3, 0.0]
POSE_B = [1.2, -0.5, 0.0, -0.5, 0.0, -0.5, 0.0, -0.3, 0.0]
ROBOT_PIXELS = 500      # servo-coloured pixels of the robot at 960x720 (1300-2600 seen)
CHANGED_PIXELS = 300    # of those, pixels that must change between the two poses


def _canvas(img: np.ndarray) -> np.ndarray:
    """The part of the 3-D canvas that viser's panels never cover at 960x720: below the
    notification (top left) and left of the control panel (top right)."""
    return img[160:, :620]


def _robot_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the servos' colour (dxl_black, 0.1 grey, shaded): dark and grey."""
    rgb = _canvas(img)[..., :3].astype(int)
    return (rgb.max(axis=2) < 90) & (rgb.max(axis=2) - rgb.min(axis=2) < 25)


@pytest.fixture
def browser():
    if not (CHROMIUM and CHROMEDRIVER):
        pytest.skip("chromium and chromedriver are installed by scripts/setup.sh")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--window-size=960,720",
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                "--disable-dev-shm-usage"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(options=opts, service=Service(CHROMEDRIVER))
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()


def _screenshot(driver) -> np.ndarray | None:
    """The page as RGB, or None when the renderer did not answer in time (software WebGL
    on a loaded machine): the caller's wait_for asks again until its deadline."""
    from PIL import Image
    from selenium.common.exceptions import TimeoutException

    try:
        png = driver.get_screenshot_as_png()
    except TimeoutException:
        return None
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def test_viewer_page_shows_the_robot_and_follows_joint_states(launch, rclpy_context,
                                                              wait_for, browser, tmp_path):
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from hyperarm_description.qos import qos_for

    viewer = launch("hyperarm_bringup", "viewer", params={"port": 0, "host": "127.0.0.1"})
    node = Node("viewer_test_publisher", namespace="/hyperarm", context=rclpy_context)
    pub = node.create_publisher(JointState, "joint_states", qos_for("joint_states"))
    pose = {"q": POSE_A}
    stop = threading.Event()

    def publish() -> None:   # like a driver: joint_states at 20 Hz
        while not stop.wait(0.05):
            msg = JointState(name=ARM, position=[float(v) for v in pose["q"]])
            pub.publish(msg)

    shots: dict[str, np.ndarray | None] = {}
    sender = threading.Thread(target=publish, daemon=True)
    sender.start()
    try:
        port = wait_for(lambda: re.search(r"http://localhost:(\d+)", viewer.output()), 60.0,
                        what="the viewer's URL in its log").group(1)
        from selenium.common.exceptions import TimeoutException
        try:
            browser.get(f"http://127.0.0.1:{port}/")
        except TimeoutException:
            pass  # the page is there; its WebGL canvas is what the screenshots wait for

        def robot_drawn():
            shots["a"] = _screenshot(browser)
            return shots["a"] is not None and _robot_mask(shots["a"]).sum() >= ROBOT_PIXELS

        wait_for(robot_drawn, 120.0, period=0.2, what="the robot on the page")
        pose["q"] = POSE_B

        def robot_moved():
            shots["b"] = _screenshot(browser)
            if shots["b"] is None:
                return False
            changed = _robot_mask(shots["a"]) != _robot_mask(shots["b"])
            return changed.sum() >= CHANGED_PIXELS and _robot_mask(
                shots["b"]).sum() >= ROBOT_PIXELS

        wait_for(robot_moved, 120.0, period=0.2, what="the robot moving on the page")
        if (keep := os.environ.get("HYPERARM_VIEWER_SCREENSHOT")):
            from PIL import Image
            Image.fromarray(shots["b"]).save(keep)
    finally:
        from PIL import Image
        for key, img in shots.items():   # kept for a failure's post-mortem
            if img is not None:
                Image.fromarray(img).save(tmp_path / f"viewer_{key}.png")
        stop.set()
        sender.join()
        node.destroy_node()
    assert viewer.proc.poll() is None, viewer.output()[-2000:]
