"""The XML launch files under ROS 2 Jazzy's rules, resolved against the installed workspace.

`launch`, `launch_xml` and `launch_ros` are apt packages on the robot and not on PyPI, so
this test applies their rules itself, as their Jazzy sources state them (ros2/launch and
ros2/launch_ros, branch jazzy), to every <arg>, <node>, <param> and <include> of every
launch file, and checks each node's resolved parameters against what the node declares
(its --help parameter table: names and types):

- Substitution syntax: ``$(name arg ...)`` as the launch frontend's design article states
  it (arguments one space apart, bare or wholly quoted with ' or ", nested substitutions,
  backslash escapes), in a grammar of our own (``launch_substitutions.lark`` beside this
  file) parsed with lark, the parser launch itself uses.
- ``<arg default>`` and ``<include><arg value>`` are text with substitutions, never typed
  (``launch/actions/declare_launch_argument.py``, ``include_launch_description.py``); a
  declared argument that nobody sets and that has no default is an error.
- ``if`` / ``unless``: the resolved text, stripped and lower-cased, must be true/1/false/0
  (``launch/conditions/evaluate_condition_expression_impl.py``).
- ``<param name value [type]>`` (``launch_ros/actions/node.py`` parse_nested_parameters):
  ``type`` maps as ``launch/frontend/type_utils.py`` get_data_type_from_identifier (str,
  bool, int, float, list_of_*; yaml or none = untyped). The raw attribute is first coerced
  with can_be_str=True (``launch_xml/entity.py`` get_attr ->
  ``launch/utilities/type_utils.py`` get_typed_value), then its substitutions are parsed
  (parse_if_substitutions). A value with substitutions is coerced after they resolve, with
  can_be_str=False (``launch_ros/parameter_descriptions.py`` ParameterValue.evaluate ->
  perform_typed_substitution -> coerce_to_type): untyped means ``yaml.safe_load`` of the
  whole resolved text, an error if that is no YAML or no scalar / uniform list;
  ``type="str"`` keeps the text.
  Hence the output of ``$(command ...)`` (e.g. a file's contents by ``cat``) in an untyped
  parameter is YAML-parsed too: a URDF fails when it holds ": " (as the generated URDF's
  header comment does), and a URDF that happens to be valid YAML is silently folded.
- ``<param from=FILE>`` (ParameterFile): a parameter file the node reads itself (rcl's YAML
  parser); its values are YAML by design.
- ``$(find-pkg-share P)``: ament_index_python's get_package_share_directory
  (``launch_ros/substitutions/find_package.py``); ``$(var N [default])``: the launch
  configuration, an error when unset (``launch/substitutions/launch_configuration.py``);
  ``$(command 'C' [on_stderr])``: shlex.split, stdout; a non-zero exit fails, and stderr
  output fails by default (``command.py``); ``$(eval E)``: Python eval with math
  (``python_expression.py``).
- ``$(eval E [MODULES])``: Python eval with the comma-separated MODULES (default math)
  as its names (``python_expression.py``, Jazzy's python_modules).
- ``<let name value>`` sets a launch configuration (``set_launch_configuration.py``).
- A node's ``<param>`` entries are passed in order, one ``--params-file`` each (a
  ``/**: ros__parameters:`` file for named values), later ones overriding earlier ones.
"""
from __future__ import annotations

import importlib
import math
import os
import random
import re
import shlex
import subprocess
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, List

import pytest
import yaml

pytestmark = pytest.mark.e2e  # runs the installed executables (--help, ik_service)

PKG = Path(__file__).resolve().parents[1]
SRC = PKG.parent
LAUNCH = sorted((PKG / "launch").glob("*.launch.xml"))
VARIANTS = ("arm", "rail_arm")
GRAMMAR = Path(__file__).with_name("launch_substitutions.lark")

#: Packages a launch file may start that are not in this workspace: apt packages on the
#: robot (ros-jazzy-*), not on PyPI. Their parameters and types are the ones their
#: documentation lists (robot_state_publisher README; rviz2 takes none).
EXTERNAL = {
    ("robot_state_publisher", "robot_state_publisher"): {
        "robot_description": "string", "publish_frequency": "float",
        "ignore_timestamp": "bool", "frame_prefix": "string"},
    ("rviz2", "rviz2"): {},
}
_PARAM = re.compile(r"^  ([a-z_][a-z0-9_]*) \(([a-z]+),", re.M)
_help_cache: dict[tuple[str, str], dict[str, str]] = {}


class LaunchError(Exception):
    """What `ros2 launch` would stop with."""


# --- substitutions (launch/frontend/parse_substitution.py) --------------------------------

@dataclass
class Sub:
    """One ``$(name arg ...)``; each argument is a list of fragments (str or Sub)."""

    name: str
    args: list = field(default_factory=list)


_parser = None


def parse_substitution(text: str) -> list:
    """The fragments (str or :class:`Sub`) of a launch-file attribute."""
    global _parser
    from lark import Lark, Token, Transformer

    if not text:
        return [text]

    def unescape(s: str) -> str:
        return re.sub(r"\\(.)", r"\1", s)

    def fragment(item):
        return unescape(item.value) if isinstance(item, Token) else item

    class Extract(Transformer):  # text and each argument: lists of str / Sub fragments
        def text(self, items):
            return [fragment(i) for i in items]
        arg = text

        def sub(self, items):
            return Sub(str(items[0]), list(items[1:]))

    if _parser is None:
        _parser = Lark(GRAMMAR.read_text(), start="text")
    return Extract().transform(_parser.parse(text))


def perform(fragments: list, ctx: dict[str, str]) -> str:
    """The text of parsed fragments in the launch configurations ``ctx``."""
    return "".join(f if isinstance(f, str) else _perform_sub(f, ctx) for f in fragments)


def _perform_sub(sub: Sub, ctx: dict[str, str]) -> str:
    args = [perform(a, ctx) for a in sub.args]
    if sub.name == "var":
        if not 1 <= len(args) <= 2:
            raise LaunchError("var substitution expects 1 or 2 arguments")
        if args[0] in ctx:
            return ctx[args[0]]
        if len(args) == 2:
            return args[1]
        raise LaunchError(f"launch configuration '{args[0]}' does not exist")
    if sub.name == "find-pkg-share":
        from ament_index_python.packages import (PackageNotFoundError,
                                                 get_package_share_directory)
        try:
            return get_package_share_directory(args[0])
        except PackageNotFoundError as exc:
            raise LaunchError(f"find-pkg-share: {exc}") from None
    if sub.name == "command":
        on_stderr = args[1] if len(args) == 2 else "fail"
        proc = subprocess.run(shlex.split(args[0]), capture_output=True, text=True, timeout=60)
        if proc.returncode != 0:
            raise LaunchError(f"executed command failed. Command: {args[0]}\n{proc.stderr}")
        if proc.stderr and on_stderr == "fail":
            raise LaunchError(f"executed command showed stderr output: {proc.stderr}")
        return proc.stdout
    if sub.name == "eval":
        if not 1 <= len(args) <= 2:
            raise LaunchError("eval substitution expects 1 or 2 arguments")
        modules = [m.strip() for m in args[1].split(",")] if len(args) == 2 else ["math"]
        names: dict[str, Any] = {}
        for module in map(importlib.import_module, modules):
            if module.__name__ == "math":
                names.update(vars(module))
            names[module.__name__] = module
        return str(eval(args[0], {}, names))  # noqa: S307 (launch does)
    raise AssertionError(f"substitution $({sub.name} ...) is not checked by this test")


# --- typed values (launch/utilities/type_utils.py) -----------------------------------------

TYPE_IDS = {"str": str, "bool": bool, "float": float, "int": int, "list_of_str": List[str],
            "list_of_bool": List[bool], "list_of_float": List[float],
            "list_of_int": List[int], "yaml": None}
SCALARS = (int, float, bool, str)


def _extract_type(data_type) -> tuple[type, bool]:
    if getattr(data_type, "__origin__", None) is list:
        return data_type.__args__[0], True
    return data_type, False


def _valid_type(value: Any, can_be_str: bool) -> bool:
    if isinstance(value, list):
        if not value:
            return True
        member = next((type(x) for x in value if type(x) is not str), str)
        if member not in SCALARS:
            return False
        return all(isinstance(x, (member, str) if can_be_str else member) for x in value)
    return isinstance(value, SCALARS)


def coerce_to_type(value: str, data_type, *, can_be_str: bool = False) -> Any:
    """launch.utilities.type_utils.coerce_to_type."""
    def as_yaml(text: str, error: str) -> Any:
        if not text:
            return text
        try:
            out = yaml.safe_load(text)
        except Exception as err:
            if can_be_str:
                return text
            raise ValueError(f"{error}: yaml.safe_load() failed\n{err}") from None
        if not _valid_type(out, can_be_str):
            raise ValueError(f"{error}: output type is not allowed, got {type(out)}")
        return out

    if data_type is None:
        return as_yaml(value, f"Failed to convert '{value}' using yaml rules")
    type_obj, is_list = _extract_type(data_type)
    valid = (str, type_obj) if can_be_str else type_obj
    if is_list:
        out = as_yaml(value, f"Cannot convert value '{value}' to a list of '{valid}'")
        if not isinstance(out, list) or not all(isinstance(x, valid) for x in out):
            raise ValueError(f"Cannot convert value '{value}' to a list of '{valid}'")
        return out
    if type_obj is str:
        return value
    if type_obj in (int, float):
        try:
            return type_obj(value)
        except ValueError:
            if can_be_str:
                return value
            raise
    value = {"1": "true", "0": "false"}.get(value, value)  # bool
    out = as_yaml(value, f"Failed to convert '{value}' to '{type_obj}'")
    if isinstance(out, valid):
        return out
    raise ValueError(f"Cannot convert value '{value}' to '{type_obj}'")


def _is_instance_of(value: Any, data_type) -> bool:
    if data_type is None:
        return _valid_type(value, False)
    type_obj, is_list = _extract_type(data_type)
    if not is_list:
        return isinstance(value, type_obj)
    return isinstance(value, list) and all(isinstance(x, type_obj) for x in value)


def param_value(el: ET.Element, ctx: dict[str, str]) -> Any:
    """The value a ``<param name value [type]>`` gives the node (launch_ros ParameterValue)."""
    type_id = el.get("type")
    if type_id is not None and type_id not in TYPE_IDS:
        raise LaunchError(f"Got invalid type identifier '{type_id}'")
    data_type = TYPE_IDS[type_id] if type_id is not None else None
    raw = el.get("value")
    if raw is None or len(el):
        raise AssertionError(f"param {el.get('name')}: nested parameters are not checked")
    try:
        first = coerce_to_type(raw, data_type, can_be_str=True)
    except ValueError as exc:
        raise LaunchError(f"param {el.get('name')}: {exc}") from None
    if not isinstance(first, str):  # a scalar without substitutions
        if not _is_instance_of(first, data_type):
            raise LaunchError(f"param {el.get('name')}: {first!r} is no {data_type}")
        return first
    fragments = parse_substitution(first)
    if len(fragments) == 1 and isinstance(fragments[0], str):
        return fragments[0]
    try:
        return coerce_to_type(perform(fragments, ctx), data_type)
    except ValueError as exc:
        raise LaunchError(f"param {el.get('name')}: {exc}") from None


# --- launch files (launch_xml) --------------------------------------------------------------

@dataclass
class LaunchedNode:
    """A <node> that would start: its parameter sources in order (("file", path) or
    ("value", name, value)) and its command-line arguments."""

    source: str
    pkg: str
    exe: str
    name: str
    namespace: str
    params: list = field(default_factory=list)
    args: list = field(default_factory=list)

    @property
    def key(self) -> str:
        return f"/{self.namespace}/{self.name}" if self.namespace else f"/{self.name}"


_NODE_ATTRS = {"pkg", "exec", "name", "namespace", "args", "if", "unless", "output"}


def _condition(el: ET.Element, ctx: dict[str, str], where: str) -> bool:
    for attr, want in (("if", True), ("unless", False)):
        if el.get(attr) is not None:
            text = perform(parse_substitution(el.get(attr)), ctx).strip().lower()
            if text not in ("true", "1", "false", "0"):
                raise LaunchError(f"{where}: condition {el.get(attr)!r} -> {text!r} is not "
                                  "one of true, 1, false, 0")
            if (text in ("true", "1")) != want:
                return False
    return True


def load_launch(path: Path, given: dict[str, str],
                parent: dict[str, str] | None = None) -> list[LaunchedNode]:
    """Every node ``path`` would start with the launch arguments ``given``."""
    root = ET.parse(path).getroot()
    assert root.tag == "launch", path
    ctx = {**(parent or {}), **given}
    nodes: list[LaunchedNode] = []
    for el in root:
        where = f"{path.name}: <{el.tag} {el.get('name') or el.get('exec') or ''}>"
        if not _condition(el, ctx, where):
            continue
        if el.tag == "arg":
            unknown = set(el.attrib) - {"name", "default", "description"}
            assert not unknown and not len(el), f"{where}: unchecked {sorted(unknown)}"
            if el.get("name") not in ctx:
                if el.get("default") is None:
                    raise LaunchError(f"{where}: required argument not given")
                ctx[el.get("name")] = perform(parse_substitution(el.get("default")), ctx)
        elif el.tag == "let":
            unknown = set(el.attrib) - {"name", "value"}
            assert not unknown and not len(el), f"{where}: unchecked {sorted(unknown)}"
            ctx[perform(parse_substitution(el.get("name")), ctx)] = \
                perform(parse_substitution(el.get("value")), ctx)
        elif el.tag == "node":
            unknown = set(el.attrib) - _NODE_ATTRS
            assert not unknown, f"{where}: unchecked attributes {sorted(unknown)}"
            node = LaunchedNode(
                path.name, *(perform(parse_substitution(el.get(a, "")), ctx)
                             for a in ("pkg", "exec", "name", "namespace")))
            node.name = node.name or node.exe
            node.args = perform(parse_substitution(el.get("args", "")), ctx).split()
            for child in el:
                assert child.tag == "param", f"{where}: unchecked <{child.tag}>"
                if child.get("from") is not None:
                    assert child.get("name") is None, f"{where}: name and from"
                    node.params.append(("file", perform(parse_substitution(child.get("from")),
                                                        ctx)))
                else:
                    name = perform(parse_substitution(child.get("name")), ctx)
                    node.params.append(("value", name, param_value(child, ctx)))
            nodes.append(node)
        elif el.tag == "include":
            target = Path(perform(parse_substitution(el.get("file")), ctx))
            if not target.exists():
                raise LaunchError(f"{where}: includes a missing {target}")
            sub = {perform(parse_substitution(a.get("name")), ctx):
                   perform(parse_substitution(a.get("value")), ctx) for a in el.findall("arg")}
            nodes += load_launch(target, sub, ctx)
        else:
            raise AssertionError(f"{where}: <{el.tag}> is not checked by this test")
    return nodes


# --- what the nodes declare ------------------------------------------------------------------

def declared(pkg: str, exe: str) -> dict[str, str]:
    """name -> type ("string", "int", "float", "bool", ...) of the parameters a node declares:
    its installed executable's --help, or EXTERNAL."""
    if (pkg, exe) in EXTERNAL:
        return EXTERNAL[(pkg, exe)]
    if (pkg, exe) not in _help_cache:
        from ament_index_python.packages import PackageNotFoundError, get_package_prefix
        try:
            path = Path(get_package_prefix(pkg)) / "lib" / pkg / exe
        except PackageNotFoundError:
            raise AssertionError(f"no package {pkg}") from None
        assert path.exists(), f"no executable {exe} in package {pkg} ({path})"
        out = subprocess.run([str(path), "--help"], capture_output=True, text=True,
                             timeout=60)
        assert out.returncode == 0, out.stderr
        _help_cache[(pkg, exe)] = dict(_PARAM.findall(out.stdout))
    return _help_cache[(pkg, exe)]


def _type_ok(value: Any, kind: str) -> bool:
    if kind == "string":
        return isinstance(value, str)
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "float":  # hyperarm's declare_parameters and rclcpp accept an int (YAML "1")
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    return isinstance(value, (list, tuple))


def effective_parameters(node: LaunchedNode) -> dict[str, Any]:
    """The parameters the node starts with, checked against its declarations."""
    names = declared(node.pkg, node.exe)
    values: dict[str, Any] = {}
    for entry in node.params:
        if entry[0] == "file":
            file = Path(entry[1])
            assert file.exists(), f"{node.source}: no parameter file {file}"
            data = yaml.safe_load(file.read_text())
            assert node.key in data, f"{file.name} has no section {node.key} for {node.exe}"
            for section in data:  # every section is for a node some launch file starts
                assert section.rsplit("/", 1)[-1] in ALL_NODES, f"{file.name}: {section}"
            new = data[node.key]["ros__parameters"]
            where = f"{file.name} {node.key}"
        else:
            new = {entry[1]: entry[2]}
            where = node.source
        for name, value in new.items():
            assert name in names, f"{where}: {node.exe} declares no parameter {name}"
            assert _type_ok(value, names[name]), \
                f"{where}: {node.exe} parameter {name} is {names[name]}, gets {value!r}"
            values[name] = value
    for arg in node.args:
        if arg.endswith(".rviz"):
            assert Path(arg).exists(), f"no RViz config {arg}"
    return values


ALL_NODES = {n.get("name") for f in LAUNCH for n in ET.parse(f).getroot().iter("node")}


def launched(name: str, **given: str) -> dict[str, tuple[LaunchedNode, dict[str, Any]]]:
    """node name -> (node, its parameters) for ``ros2 launch hyperarm_bringup name given``."""
    nodes = load_launch(PKG / "launch" / name, given)
    return {n.name: (n, effective_parameters(n)) for n in nodes}


# --- tests -----------------------------------------------------------------------------------

def _urdf(variant: str) -> Path:
    from ament_index_python.packages import get_package_share_directory
    return Path(get_package_share_directory("hyperarm_description")) / "urdf" / \
        f"hyperarm_{variant}.urdf"


def test_there_are_launch_files_for_mock_and_hardware():
    assert {p.name for p in LAUNCH} >= {"mock.launch.xml", "hardware.launch.xml"}


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", ["mock.launch.xml", "hardware.launch.xml"])
def test_launch_file_starts_under_jazzy_rules(name, variant):
    """Every <arg>, <param> and <include> resolves as Jazzy resolves it, every parameter is
    declared with that type, and the URDF reaches robot_state_publisher unchanged (the
    generated URDF's header comment holds ': ', so an untyped parameter fails here)."""
    workcell = str(SRC / "hyperarm_driver" / "config" / "workcell.yaml")
    for force in ("false", "true"):
        nodes = launched(name, variant=variant, rviz="true", force=force,
                         tf_publisher="robot_state_publisher")
        driver = "mock_driver" if name.startswith("mock") else "dynamixel_driver"
        assert driver in nodes and "robot_state_publisher" in nodes and "ik_service" in nodes
        assert ("pmac_rail_driver" in nodes) == (name.startswith("hardware")
                                                 and variant == "rail_arm")
        assert ("hybrid_force" in nodes) == (force == "true")
        assert {"arm_controller", "gripper_controller"} <= set(nodes)  # controllers:=true
        assert ("rviz2" in nodes) is True
        urdf = _urdf(variant)
        assert ": " in urdf.read_text()  # the case that broke Jazzy's untyped parameter
        assert nodes["robot_state_publisher"][1]["robot_description"] == urdf.read_text()
        assert nodes["robot_state_publisher"][1]["publish_frequency"] == 50.0
        # issue 24.8: ik_service avoids the work cell the mock simulates
        world = nodes["ik_service"][1]["world_file"]
        assert Path(world).resolve() == Path(workcell).resolve()
        if driver == "mock_driver":
            assert nodes["mock_driver"][1]["workcell_file"] == world
    assert "rviz2" not in launched(name, variant=variant, rviz="false")


CONTROLLERS = {"arm_controller": "FollowJointTrajectory",
               "gripper_controller": "GripperCommand"}


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", ["mock.launch.xml", "hardware.launch.xml"])
def test_controllers_start_unless_controllers_false(name, variant):
    """issue 26: arm_controller (FollowJointTrajectory) and gripper_controller
    (GripperCommand), hyperarm_control's console scripts, start by default (controllers:=true)
    in /hyperarm with the variant's parameter file, like the other hyperarm nodes, and only
    with parameters they declare (launched() checks them against --help);
    controllers:=false starts neither and nothing else changes. The argument is a launch
    condition: Jazzy takes true/1/false/0 only."""
    default = launched(name, variant=variant, rviz="false")
    assert set(CONTROLLERS) <= set(default)
    task_node = default["task_node"][0]
    for exe in CONTROLLERS:
        node, params = default[exe]
        assert (node.pkg, node.exe, node.name, node.namespace) == \
            ("hyperarm_control", exe, exe, "hyperarm")
        assert node.key == f"/hyperarm/{exe}"
        # the same parameter file as the other nodes: the variant's, nothing else
        assert node.params == task_node.params
        assert [Path(p[1]).name for p in node.params] == [f"{variant}.yaml"]
        assert params["variant"] == variant
        assert node.args == []
    for on in ("true", "1", "True"):
        assert set(launched(name, variant=variant, rviz="false", controllers=on)) == \
            set(default)
    for off in ("false", "0"):
        nodes = launched(name, variant=variant, rviz="false", controllers=off)
        assert set(nodes) == set(default) - set(CONTROLLERS)
    # independent of force:=
    nodes = launched(name, variant=variant, rviz="false", force="true", controllers="false")
    assert "hybrid_force" in nodes and not set(CONTROLLERS) & set(nodes)
    with pytest.raises(LaunchError, match="not one of true"):
        launched(name, variant=variant, rviz="false", controllers="yes")


def test_the_controllers_argument_is_declared_and_passed_through():
    """mock.launch.xml and hardware.launch.xml declare controllers (default true) and hand
    it to common.launch.xml, which declares it too (so it also works on its own)."""
    for path in LAUNCH:
        root = ET.parse(path).getroot()
        args = {a.get("name"): a for a in root.findall("arg")}
        assert args["controllers"].get("default") == "true", path.name
        assert args["controllers"].get("description"), path.name
        for include in root.findall("include"):
            passed = {a.get("name"): a.get("value") for a in include.findall("arg")}
            assert passed.get("controllers") == "$(var controllers)", path.name


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", ["mock.launch.xml", "hardware.launch.xml"])
def test_tf_comes_from_robot_state_publisher_where_installed_else_ours(name, variant,
                                                                      tmp_path, monkeypatch):
    """tf_publisher:=robot_state_publisher or :=tf_publisher starts that one alone; auto
    (the default) asks the ament index, as Jazzy's eval with ament_index_python does: ours
    here (no robot_state_publisher on PyPI), robot_state_publisher once a prefix has it
    (/opt/ros/jazzy on the robot); any other value stops the launch."""
    from ament_index_python import has_resource

    both = {"robot_state_publisher", "tf_publisher"}
    for choice in sorted(both):
        nodes = launched(name, variant=variant, rviz="false", tf_publisher=choice)
        assert both & set(nodes) == {choice}
    node, params = nodes["tf_publisher"]
    assert node.namespace == "hyperarm" and params["variant"] == variant
    installed = bool(has_resource("packages", "robot_state_publisher"))
    assert both & set(launched(name, variant=variant, rviz="false")) == \
        {"robot_state_publisher" if installed else "tf_publisher"}
    index = tmp_path / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    (index / "robot_state_publisher").touch()
    monkeypatch.setenv("AMENT_PREFIX_PATH",
                       f"{tmp_path}{os.pathsep}{os.environ['AMENT_PREFIX_PATH']}")
    assert both & set(launched(name, variant=variant, rviz="false")) == \
        {"robot_state_publisher"}
    with pytest.raises(ValueError, match="'tf2' is not in list"):
        launched(name, variant=variant, rviz="false", tf_publisher="tf2")


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_string_arguments_reach_the_nodes_as_text(seed, tmp_path):
    """Arguments a user passes (ports, hosts, files) arrive as the same text, also when
    YAML would read them as a number, a bool or a mapping."""
    rng = random.Random(seed)
    texts = ["10", "1.5", "true", "no", "on", "0x1F", "a: b", "[1, 2]", "~", "2026-12-04"]
    port, host, name = (rng.choice(texts) for _ in range(3))
    cell = tmp_path / f"{name}.yaml"
    nodes = launched("hardware.launch.xml", variant="rail_arm", rviz="false",
                     port=port, pmac_host=host, workcell_file=str(cell))
    assert nodes["dynamixel_driver"][1]["port"] == port
    assert nodes["pmac_rail_driver"][1]["host"] == host
    assert nodes["ik_service"][1]["world_file"] == str(cell)
    nodes = launched("mock.launch.xml", variant=rng.choice(VARIANTS), workcell_file=str(cell))
    assert nodes["mock_driver"][1]["workcell_file"] == str(cell)


def _rsp_launch(tmp_path: Path, urdf_text: str, type_attr: str) -> Path:
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(urdf_text)
    f = tmp_path / "rsp.launch.xml"
    f.write_text(f'<launch><node pkg="robot_state_publisher" exec="robot_state_publisher">'
                 f'<param name="robot_description" {type_attr} '
                 f'value="$(command \'cat {urdf}\')"/></node></launch>')
    return f


def test_a_yaml_hostile_urdf_comment_needs_the_typed_parameter(tmp_path):
    """An untyped parameter holding a URDF is YAML-parsed after $(command) resolves: a
    comment with ': ' fails as on the robot, type="str" passes the text unchanged."""
    text = ('<?xml version="1.0"?>\n<!-- Do not edit: edit the YAML and regenerate -->\n'
            '<robot name="r"><link name="base_link"/></robot>\n')
    with pytest.raises(LaunchError, match="(?s)Failed to convert .* using yaml rules"):
        load_launch(_rsp_launch(tmp_path, text, ""), {})
    node, = load_launch(_rsp_launch(tmp_path, text, 'type="str"'), {})
    assert effective_parameters(node)["robot_description"] == text
    # a URDF that happens to be valid YAML is not refused but folded into one line
    plain = '<robot name="r">\n  <link name="base_link"/>\n</robot>\n'
    node, = load_launch(_rsp_launch(tmp_path, plain, ""), {})
    assert node.params[0][2] != plain and "\n" not in node.params[0][2]
    node, = load_launch(_rsp_launch(tmp_path, plain, 'type="str"'), {})
    assert node.params[0][2] == plain


@pytest.mark.parametrize("text, want", [
    ("plain text", ["plain text"]),
    ("$(var a)", [Sub("var", [["a"]])]),
    ("x=$(var a)/y", ["x=", Sub("var", [["a"]]), "/y"]),
    ("$(var a b)", [Sub("var", [["a"], ["b"]])]),
    ("$(command 'cat $(find-pkg-share p)/u.urdf')",
     [Sub("command", [["cat ", Sub("find-pkg-share", [["p"]]), "/u.urdf"]])]),
    ('$(var n "two words")', [Sub("var", [["n"], ["two words"]])]),
    ("$(var n '')", [Sub("var", [["n"], []])]),
    ("cost: 5$ \\$(var a)", ["cost: 5$ $(var a)"]),       # "$" without "(" and an escape
    ("$(eval '1 + 2')", [Sub("eval", [["1 + 2"]])]),
])
def test_substitution_syntax(text, want):
    """The documented substitution syntax: nesting, quoting, escapes, a lone '$'."""
    assert parse_substitution(text) == want


@pytest.mark.parametrize("text", ["$(var a", "$(var  a)", "$(var 'a'b)", "$()"])
def test_substitution_syntax_errors_are_refused(text):
    from lark.exceptions import LarkError
    with pytest.raises(LarkError):
        parse_substitution(text)


@pytest.mark.parametrize("raw,type_attr,want", [
    ("50.0", "", 50.0), ("50.0", 'type="str"', "50.0"), ("true", "", True),
    ("1", 'type="bool"', True), ("7", 'type="float"', 7.0), ("[1, 2]", "", [1, 2]),
    ("[1.0, 2.5]", 'type="list_of_float"', [1.0, 2.5]), ("/dev/ttyUSB0", "", "/dev/ttyUSB0"),
    ("a: b", 'type="str"', "a: b"), ("$(var x)", "", 12), ("$(var x)", 'type="str"', "12"),
    ("$(var x).5", "", 12.5), ("p_$(var x)", "", "p_12"), ("$(var y 'n: 1')", 'type="str"', "n: 1"),
])
def test_param_values_follow_jazzy_typing(raw, type_attr, want, tmp_path):
    f = tmp_path / "p.launch.xml"
    f.write_text(f'<launch><node pkg="rviz2" exec="rviz2"><param name="p" {type_attr} '
                 f'value="{raw}"/></node></launch>')
    node, = load_launch(f, {"x": "12"})
    value = node.params[0][2]
    assert value == want and type(value) is type(want), value


@pytest.mark.parametrize("body,match", [
    ('<param name="p" value="$(var x)"/>', "using yaml rules"),     # x = "a: b: c"
    ('<param name="p" value="$(var nosuch)"/>', "nosuch' does not exist"),
    ('<param name="p" type="int" value="$(var x)"/>', "invalid literal"),
    ('<param name="p" type="float64" value="1"/>', "invalid type identifier"),
    ('<param name="p" value="$(command \'false\')"/>', "executed command failed"),
])
def test_param_values_jazzy_refuses(body, match, tmp_path):
    f = tmp_path / "p.launch.xml"
    f.write_text(f'<launch><node pkg="rviz2" exec="rviz2">{body}</node></launch>')
    with pytest.raises((LaunchError, ValueError), match=match):
        load_launch(f, {"x": "a: b: c"})


def test_arguments_and_conditions_follow_jazzy_rules(tmp_path):
    f = tmp_path / "a.launch.xml"
    f.write_text('<launch><arg name="need"/><arg name="on" default="True "/>'
                 '<node pkg="rviz2" exec="rviz2" name="n1" if="$(var on)"/>'
                 '<node pkg="rviz2" exec="rviz2" name="n2" unless="$(var on)"/>'
                 '<node pkg="rviz2" exec="rviz2" name="n3" '
                 'if="$(eval &quot;\'$(var need)\' == \'x y\'&quot;)"/></launch>')
    with pytest.raises(LaunchError, match="required argument"):
        load_launch(f, {})
    assert [n.name for n in load_launch(f, {"need": "x y"})] == ["n1", "n3"]
    assert [n.name for n in load_launch(f, {"need": "z", "on": "0"})] == ["n2"]
    with pytest.raises(LaunchError, match="not one of true"):
        load_launch(f, {"need": "z", "on": "yes"})
    frags = parse_substitution(r"a\$(b) $(var 'x y') $(find-pkg-share \"q\")")
    assert frags[0] == "a$(b) " and frags[1] == Sub("var", [["x y"]])


def test_the_checker_catches_undeclared_and_mistyped_parameters(tmp_path):
    bad = tmp_path / "bad.launch.xml"
    bad.write_text('<launch><node pkg="hyperarm_ik" exec="fk_node" name="fk_node">'
                   '<param name="no_such_parameter" value="1"/></node></launch>')
    with pytest.raises(AssertionError, match="no_such_parameter"):
        effective_parameters(load_launch(bad, {})[0])
    bad.write_text('<launch><node pkg="hyperarm_ik" exec="ik_service" name="ik_service">'
                   '<param name="timeout" value="fast"/></node></launch>')
    with pytest.raises(AssertionError, match="timeout is float, gets 'fast'"):
        effective_parameters(load_launch(bad, {})[0])
    bad.write_text('<launch><node pkg="hyperarm_ik" exec="ik_service" name="ik_service">'
                   '<param name="world_file" value="10"/></node></launch>')
    with pytest.raises(AssertionError, match="world_file is string, gets 10"):
        effective_parameters(load_launch(bad, {})[0])
    bad.write_text('<launch><node pkg="hyperarm_ik" exec="no_such_exe"/></launch>')
    with pytest.raises(AssertionError, match="no executable"):
        effective_parameters(load_launch(bad, {})[0])


# --- issue 24.8: the launched ik_service avoids the work cell --------------------------------

def _start_as_launched(launch, tmp_path: Path, node: LaunchedNode):
    """Start the installed executable with the node's parameters as launch_ros passes them:
    one --params-file per <param>, in order."""
    files = []
    for i, entry in enumerate(node.params):
        if entry[0] == "file":
            files.append(entry[1])
        else:
            f = tmp_path / f"{node.name}-{i}.yaml"
            f.write_text(yaml.safe_dump({"/**": {"ros__parameters": {entry[1]: entry[2]}}}))
            files.append(str(f))
    args = ["--ros-args", "-r", f"__ns:=/{node.namespace}"]
    for f in files:
        args += ["--params-file", f]
    return launch(node.pkg, node.exe, *args)


def _ik(executable, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([executable("hyperarm_bringup", "hyperarm"), "ik", *args,
                           "--timeout", "30"], capture_output=True, text=True, timeout=90,
                          env=dict(os.environ))


@pytest.mark.slow
def test_launched_ik_service_refuses_targets_in_the_table(launch, executable, wait_for,
                                                         tmp_path):
    """`hyperarm ik 0.35 0 -0.25` (5 cm below the table) has no solution from the ik_service
    mock.launch.xml starts, and its first log line names the work cell (variant arm: the
    CLI's targets are in base_link; hardware.launch.xml passes the same ik_service
    parameters: test_launch_file_starts_under_jazzy_rules)."""
    from hyperarm_description.world import load_world

    variant = "arm"
    node, params = launched("mock.launch.xml", variant=variant, rviz="false")["ik_service"]
    world = load_world(params["world_file"])
    proc = _start_as_launched(launch, tmp_path, node)
    assert wait_for(lambda: "ik_service" in proc.output(), timeout=60), proc.output()
    first = proc.output().splitlines()[0]
    assert f"work cell {params['world_file']}" in first, first
    rng = random.Random(variant)
    below = [(0.35, 0.0, -0.25)] + [(rng.uniform(0.25, 0.45), rng.uniform(-0.15, 0.15),
                                     world.table_height - rng.uniform(0.02, 0.08))
             for _ in range(2)]
    for x, y, z in below:
        r = _ik(executable, f"{x:.3f}", f"{y:.3f}", f"{z:.3f}")
        assert r.returncode == 1 and "no solution" in r.stderr, (x, y, z, r.stdout, r.stderr)
        assert "refused" not in r.stderr and "table" in r.stderr, r.stderr  # solved, in contact
    r = _ik(executable, "0.35", "0", f"{world.table_height + 0.25:.3f}")
    assert r.returncode == 0 and "position error" in r.stdout, r.stderr


@pytest.mark.slow
def test_a_standalone_ik_service_says_it_avoids_no_work_cell(launch, wait_for):
    proc = launch("hyperarm_ik", "ik_service")
    assert wait_for(lambda: "ik_service" in proc.output(), timeout=60), proc.output()
    first = proc.output().splitlines()[0]
    assert "no work cell" in first and "world_file" in first, first


# --- issue 26: the launched controllers ------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("variant", VARIANTS)
def test_launched_controllers_serve_their_actions_and_stay_silent(
        variant, launch, rclpy_context, executor, wait_for, tmp_path):
    """mock_driver, arm_controller and gripper_controller as mock.launch.xml starts them
    (namespace, parameter file): both controllers load the variant's joints, offer their
    actions once joint_states arrive, and publish nothing on joint_command while idle (the
    one-commander rule, docs/architecture.md: other commanders such as task_node are free
    to command the arm and gripper while no goal runs); then a gripper goal is heard
    streaming joint_command for the gripper alone."""
    import rclpy
    from control_msgs.action import FollowJointTrajectory, GripperCommand
    from rclpy.action import ActionClient
    from sensor_msgs.msg import JointState

    from hyperarm_control.client import in_executor
    from hyperarm_description import contract
    from hyperarm_description.model import load_description
    from hyperarm_description.qos import qos_for

    nodes = launched("mock.launch.xml", variant=variant, rviz="false")
    node = rclpy.create_node("launch_probe", namespace="/hyperarm", context=rclpy_context)
    commands: list = []
    node.create_subscription(JointState, contract.JOINT_COMMAND, commands.append,
                             qos_for(contract.JOINT_COMMAND))
    clients = {"arm_controller": ActionClient(node, FollowJointTrajectory,
                                              contract.ARM_TRAJECTORY_ACTION),
               "gripper_controller": ActionClient(node, GripperCommand,
                                                  contract.GRIPPER_ACTION)}
    executor.add_node(node)
    procs = {name: _start_as_launched(launch, tmp_path, nodes[name][0])
             for name in ("mock_driver", *CONTROLLERS)}
    for name in CONTROLLERS:
        wait_for(lambda: "serving" in procs[name].output(), 60.0,
                 what=lambda: f"{name} serving its action\n{procs[name].output()}")
        wait_for(clients[name].server_is_ready, 30.0, what=f"{name}'s action server")
    first = procs["arm_controller"].output()
    assert ("rail, joint1" in first) == (variant == "rail_arm"), first
    time.sleep(2.0)                      # idle: 200 arm and 100 gripper cycles
    assert commands == [], [(c.name, list(c.position)) for c in commands[:3]]
    # the probe does hear joint_command: a gripper goal (open) streams it, gripper only
    goal = GripperCommand.Goal()
    goal.command.position = float(load_description(None, variant).gripper.upper)
    sent = in_executor(node, lambda: clients["gripper_controller"].send_goal_async(goal))
    wait_for(lambda: sent.done(), 30.0, what="the gripper goal's acceptance")
    result = in_executor(node, sent.result().get_result_async)
    wait_for(lambda: result.done(), 30.0, what="the gripper goal's result")
    assert result.result().result.reached_goal, result.result()
    assert commands and all(list(c.name) == ["gripper"] for c in commands), commands[:3]
    for proc in procs.values():
        assert proc.proc.poll() is None, proc.output()
