from glob import glob

from setuptools import find_packages, setup

package_name = "hyperarm_bringup"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.xml")),
        ("share/" + package_name + "/config", glob("config/*.yaml") + glob("config/*.xml")),
        ("share/" + package_name + "/rviz", glob("rviz/*.rviz")),
        ("share/" + package_name + "/udev", glob("udev/*.rules")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hyperarm developers",
    maintainer_email="dev@hyperarm.invalid",
    description="hyperarm bring-up: launch files, parameter files, RViz config, udev rules, "
                "the hyperarm CLI and the browser viewer.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "hyperarm = hyperarm_bringup.cli:main",
            "viewer = hyperarm_bringup.entry:viewer",
        ],
    },
)
