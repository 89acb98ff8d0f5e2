from glob import glob

from setuptools import find_packages, setup

package_name = "hyperarm_ik"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hyperarm developers",
    maintainer_email="dev@hyperarm.invalid",
    description="hyperarm kinematics (pinocchio), IK solvers, the IK service node and the TF publisher.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "fk_node = hyperarm_ik.entry:fk_node",
            "tf_publisher = hyperarm_ik.entry:tf_publisher",
            "ik_service = hyperarm_ik.entry:ik_service",
            "ik_benchmark = hyperarm_ik.benchmark.ik_benchmark:main",
        ],
    },
)
