from glob import glob

from setuptools import find_packages, setup

package_name = "hyperarm_tasks"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/tasks", glob("tasks/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
        # shell scripts, runnable as `ros2 run hyperarm_tasks <script>.sh`
        ("lib/" + package_name, glob("scripts/*.sh")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hyperarm developers",
    maintainer_email="dev@hyperarm.invalid",
    description="hyperarm task node (pick-and-place and other sequences) and shell scripts.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "task_node = hyperarm_tasks.entry:task_node",
            "run_task = hyperarm_tasks.run_task:entry",
            "task_recorder = hyperarm_tasks.entry:task_recorder",
            "plot_task = hyperarm_tasks.plots:main",
            "soak_block_transfer = hyperarm_tasks.benchmarks.soak:main",
            "host_plots = hyperarm_tasks.benchmarks.host_plots:main",
        ],
    },
)
