from glob import glob

from setuptools import find_packages, setup

package_name = "hyperarm_driver"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/config/host_motion", glob("config/host_motion/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hyperarm developers",
    maintainer_email="dev@hyperarm.invalid",
    description="hyperarm drivers: Dynamixel bus driver, PMAC rail driver, mock driver, and emulators of the real wire protocols.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "mock_driver = hyperarm_driver.entry:mock_driver",
            "dynamixel_driver = hyperarm_driver.entry:dynamixel_driver",
            "pmac_rail_driver = hyperarm_driver.entry:pmac_rail_driver",
            "dxl_emulator = hyperarm_driver.dynamixel.emulator:main",
            "pmac_emulator = hyperarm_driver.pmac.emulator:main",
            "dxl_benchmark = hyperarm_driver.benchmarks.dxl_benchmark:main",
            "pmac_benchmark = hyperarm_driver.benchmarks.pmac_benchmark:main",
            "mock_benchmark = hyperarm_driver.benchmarks.mock_benchmark:main",
        ],
    },
)
