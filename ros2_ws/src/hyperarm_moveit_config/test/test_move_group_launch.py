"""launch/move_group.launch.py without MoveIt: it parses, names files that exist (in the
package and where colcon installs them), and, run against stand-ins of launch, launch_ros
and moveit_configs_utils that take Jazzy's signatures, hands move_group the generated files
of the chosen variant in the hyperarm namespace."""
from __future__ import annotations

import ast
import importlib.util
import sys
import types
from importlib import resources
from pathlib import Path

import pytest
import yaml

from hyperarm_description.model import VARIANTS
from hyperarm_moveit_config.generate import LAUNCH_FILE, config_paths, package_dir

pytestmark = pytest.mark.core

LAUNCH = package_dir() / LAUNCH_FILE
ROOT = Path(__file__).resolve().parents[4]
SHARE = ROOT / "ros2_ws" / "install" / "hyperarm_moveit_config" / "share" / "hyperarm_moveit_config"
DESCRIPTION = Path(str(resources.files("hyperarm_description")))


def _constants() -> dict[str, object]:
    """The launch file's module-level constants (literals), read without running it."""
    out = {}
    for node in ast.parse(LAUNCH.read_text()).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                and isinstance(node.targets[0], ast.Name):
            out[node.targets[0].id] = ast.literal_eval(node.value)
    return out


def test_it_parses_and_imports_only_launch_and_moveit_modules():
    tree = ast.parse(LAUNCH.read_text())
    modules = {n.module for n in tree.body if isinstance(n, ast.ImportFrom)}
    assert modules == {"pathlib", "ament_index_python.packages", "launch", "launch.actions",
                       "launch.substitutions", "launch_ros.actions", "moveit_configs_utils"}
    functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert "generate_launch_description" in functions


def test_the_files_it_names_exist():
    consts = _constants()
    assert set(consts["CONFIG"]) == set(VARIANTS) == set(consts["URDF"])
    assert consts["NAMESPACE"] == "hyperarm" and consts["PACKAGE"] == "hyperarm_moveit_config"
    for variant in VARIANTS:
        assert consts["CONFIG"][variant] == config_paths(variant)
        for rel in consts["CONFIG"][variant].values():
            assert (package_dir() / rel).is_file(), rel
        assert (DESCRIPTION / consts["URDF"][variant]).is_file()


@pytest.mark.skipif(not SHARE.is_dir(), reason="the workspace is not built (colcon build)")
def test_colcon_installs_them_where_the_launch_file_looks():
    consts = _constants()
    assert (SHARE / LAUNCH_FILE).is_file()
    share_description = SHARE.parents[2] / "hyperarm_description" / "share" / "hyperarm_description"
    for variant in VARIANTS:
        for rel in consts["CONFIG"][variant].values():
            assert (SHARE / rel).read_text() == (package_dir() / rel).read_text(), rel
        assert (share_description / consts["URDF"][variant]).is_file()


# --- stand-ins with the signatures of Jazzy's launch, launch_ros and moveit_configs_utils ---
class _Builder:
    """MoveItConfigsBuilder's Jazzy API: each file_path is relative to the config package's
    share directory (or absolute), and is loaded here as the real builder loads it."""

    def __init__(self, robot_name, robot_description="robot_description", package_name=None):
        self.package = Path(_share(package_name or robot_name + "_moveit_config"))
        self.params = {}

    def _file(self, file_path):
        path = self.package / file_path
        assert path.is_file(), path
        return path

    def robot_description(self, file_path=None, mappings=None):
        self.params["robot_description"] = self._file(file_path).read_text()
        return self

    def robot_description_semantic(self, file_path=None, mappings=None):
        self.params["robot_description_semantic"] = self._file(file_path).read_text()
        return self

    def robot_description_kinematics(self, file_path=None):
        self.params["robot_description_kinematics"] = yaml.safe_load(
            self._file(file_path).read_text())
        return self

    def joint_limits(self, file_path=None):
        self.params["robot_description_planning"] = yaml.safe_load(
            self._file(file_path).read_text())
        return self

    def trajectory_execution(self, file_path=None, moveit_manage_controllers=True):
        self.params["moveit_manage_controllers"] = moveit_manage_controllers
        self.params.update(yaml.safe_load(self._file(file_path).read_text()))
        return self

    def planning_pipelines(self, default_planning_pipeline=None, pipelines=None, load_all=True):
        self.params["planning_pipelines"] = pipelines
        return self

    def to_moveit_configs(self):
        return types.SimpleNamespace(to_dict=lambda: dict(self.params))


def _share(package: str) -> str:
    return str({"hyperarm_description": DESCRIPTION,
                "hyperarm_moveit_config": package_dir()}[package])


class _Record:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class _LaunchConfiguration(_Record):
    def perform(self, context):
        return context[self.args[0]]


def _stand_ins(monkeypatch) -> None:
    def module(name, **attrs):
        monkeypatch.setitem(sys.modules, name, types.SimpleNamespace(**attrs))
    module("ament_index_python")
    module("ament_index_python.packages", get_package_share_directory=_share)
    module("launch", LaunchDescription=_Record)
    module("launch.actions", DeclareLaunchArgument=_Record, OpaqueFunction=_Record)
    module("launch.substitutions", LaunchConfiguration=_LaunchConfiguration)
    module("launch_ros")
    module("launch_ros.actions", Node=_Record)
    module("moveit_configs_utils", MoveItConfigsBuilder=_Builder)


@pytest.mark.parametrize("variant", VARIANTS)
def test_move_group_gets_the_variants_files(monkeypatch, variant):
    _stand_ins(monkeypatch)
    spec = importlib.util.spec_from_file_location("move_group_launch", LAUNCH)
    launch_file = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(launch_file)
    (entities,) = launch_file.generate_launch_description().args
    arguments = {e.args[0]: e.kwargs for e in entities if "function" not in e.kwargs}
    assert arguments["variant"]["default_value"] == "arm"
    assert set(arguments["variant"]["choices"]) == set(VARIANTS)
    assert arguments["namespace"]["default_value"] == "hyperarm"
    (opaque,) = [e for e in entities if "function" in e.kwargs]
    (node,) = opaque.kwargs["function"]({"variant": variant, "namespace": "hyperarm"})
    assert (node.kwargs["package"], node.kwargs["executable"]) == ("moveit_ros_move_group",
                                                                  "move_group")
    assert node.kwargs["namespace"].perform({"namespace": "hyperarm"}) == "hyperarm"
    params = {}
    for p in node.kwargs["parameters"]:
        params.update(p)
    files = {role: (package_dir() / rel).read_text()
             for role, rel in config_paths(variant).items()}
    assert params["robot_description"] == \
        (DESCRIPTION / f"urdf/hyperarm_{variant}.urdf").read_text()
    assert params["robot_description_semantic"] == files["srdf"]
    assert params["robot_description_kinematics"] == yaml.safe_load(files["kinematics"])
    assert params["robot_description_planning"] == yaml.safe_load(files["joint_limits"])
    assert params["moveit_simple_controller_manager"] == \
        yaml.safe_load(files["controllers"])["moveit_simple_controller_manager"]
    assert params["moveit_manage_controllers"] is False
    assert params["planning_pipelines"] == ["ompl"]
