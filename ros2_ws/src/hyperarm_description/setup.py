from glob import glob

from setuptools import find_packages, setup

package_name = "hyperarm_description"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={package_name: ["config/*.yaml", "urdf/*.urdf"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob(package_name + "/config/*.yaml")),
        ("share/" + package_name + "/urdf", glob(package_name + "/urdf/*.urdf")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="hyperarm developers",
    maintainer_email="dev@hyperarm.invalid",
    description="hyperarm robot description (YAML, URDF, MJCF, pinocchio models)",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "generate_urdf = hyperarm_description.urdf:main",
            "generate_mjcf = hyperarm_description.mjcf:main",
            "show_description = hyperarm_description.show:main",
        ],
    },
)
