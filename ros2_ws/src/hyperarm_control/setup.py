from setuptools import find_packages, setup

package_name = "hyperarm_control"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", ["config/wave.yaml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hyperarm developers",
    maintainer_email="dev@hyperarm.invalid",
    description="hyperarm controllers: the joint trajectory core and arm_controller "
                "(FollowJointTrajectory), gripper_controller (GripperCommand), the hybrid "
                "force controller, host-motion compensation, force calibration, and their "
                "benchmarks",
    license="Apache-2.0",
    entry_points={"console_scripts": [
        "arm_controller = hyperarm_control.entry:arm_controller",
        "gripper_controller = hyperarm_control.entry:gripper_controller",
        "trajectory_benchmark = hyperarm_control.benchmark.trajectory_benchmark:main",
        "hybrid_force = hyperarm_control.entry:hybrid_force",
        "hybrid_force_calibrate = hyperarm_control.entry:hybrid_force_calibrate",
        "force_benchmark = hyperarm_control.benchmark.force_benchmark:main",
        "host_benchmark = hyperarm_control.benchmark.host_benchmark:main",
        "host_compensation = hyperarm_control.entry:host_compensation",
    ]},
)
