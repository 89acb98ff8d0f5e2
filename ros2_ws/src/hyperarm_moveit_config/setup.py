from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = "hyperarm_moveit_config"
# the generated files (hyperarm_moveit_config.generate) live in the Python package's folder,
# like hyperarm_description's URDFs, and are installed where MoveIt looks: share/<package>/
config_dirs = sorted(p.name for p in Path(package_name, "config").iterdir() if p.is_dir())

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["config/*/*", "launch/*.launch.py"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", glob(package_name + "/launch/*.launch.py")),
    ] + [("share/" + package_name + "/config/" + d, glob(f"{package_name}/config/{d}/*"))
         for d in config_dirs],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hyperarm developers",
    maintainer_email="dev@hyperarm.invalid",
    description="hyperarm's MoveIt 2 configuration (SRDF, joint limits, kinematics, "
                "controllers, move_group launch file), generated from the robot description",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "generate_moveit_config = hyperarm_moveit_config.generate:main",
        ],
    },
)
