from glob import glob

from setuptools import find_packages, setup

package_name = "hyperarm_perception"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["config/*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob(package_name + "/config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hyperarm developers",
    maintainer_email="dev@hyperarm.invalid",
    description="hyperarm perception: marker detector core and hand-eye calibration math",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "marker_detector = hyperarm_perception.entry:marker_detector",
            "usb_camera = hyperarm_perception.entry:usb_camera",
            "mock_camera = hyperarm_perception.entry:mock_camera",
            "calibrate_camera = hyperarm_perception.entry:calibrate_camera",
        ],
    },
)
