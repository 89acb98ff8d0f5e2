"""The XML launch files name only things that exist: packages, executables, parameter files,
and parameters that the node declares (read from the node's own --help, i.e. its parameter
table). `launch` itself is not installable on the PyPI route, so the files are checked as
XML here; they run on the robot with `ros2 launch`."""
from __future__ import annotations

import re
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.e2e  # runs the installed executables (--help)

PKG = Path(__file__).resolve().parents[1]
SRC = PKG.parent
INSTALL = SRC.parent / "install"
LAUNCH = sorted((PKG / "launch").glob("*.launch.xml"))
VARIANTS = ("arm", "rail_arm")

#: Packages a launch file may start that are not in this workspace: apt packages on the
#: robot (ros-jazzy-*), not on PyPI, so not installable here. Their parameters are the
#: ones their documentation lists (robot_state_publisher README; rviz2 takes none).
EXTERNAL = {
    ("robot_state_publisher", "robot_state_publisher"): {
        "robot_description", "publish_frequency", "ignore_timestamp", "frame_prefix"},
    ("rviz2", "rviz2"): set(),
}
_PARAM = re.compile(r"^  ([a-z_][a-z0-9_]*) \((?:string|int|float|bool)", re.M)
_help_cache: dict[tuple[str, str], set[str]] = {}


def declared(pkg: str, exe: str) -> set[str]:
    """The parameters a workspace node declares, from its installed executable's --help."""
    if (pkg, exe) not in _help_cache:
        path = INSTALL / pkg / "lib" / pkg / exe
        assert path.exists(), f"no executable {exe} in package {pkg} ({path})"
        out = subprocess.run([str(path), "--help"], capture_output=True, text=True,
                             timeout=60)
        assert out.returncode == 0, out.stderr
        _help_cache[(pkg, exe)] = set(_PARAM.findall(out.stdout))
    return _help_cache[(pkg, exe)]


def substitute(text: str, args: dict[str, str]) -> str:
    """$(var), $(find-pkg-share) resolved (workspace packages: their source share files)."""
    def one(m: re.Match) -> str:
        kind, _, rest = m.group(1).partition(" ")
        if kind == "var":
            assert rest in args, f"$(var {rest}) without an <arg>"
            return args[rest]
        if kind == "find-pkg-share":
            assert (SRC / rest / "package.xml").exists(), f"no package {rest}"
            return f"{SRC / rest}::share"
        raise AssertionError(f"unchecked substitution $({m.group(1)})")
    prev = None
    while prev != text:
        prev, text = text, re.sub(r"\$\(((?:var|find-pkg-share) [A-Za-z0-9_]+)\)", one, text)
    return text


def share_file(path: str) -> Path:
    """A share/ path as its source file (colcon installs them from the package sources)."""
    pkg, _, rel = path.partition("::share")
    pkg_dir = Path(pkg)
    rel = rel.lstrip("/")
    candidates = [pkg_dir / rel, pkg_dir / pkg_dir.name / rel]
    return next((c for c in candidates if c.exists()), candidates[0])


def check_launch(path: Path, given: dict[str, str], seen: list[str]) -> None:
    root = ET.parse(path).getroot()
    assert root.tag == "launch", path
    args = {}
    for arg in root.iter("arg"):
        if arg in list(root):  # a declaration at top level
            args[arg.get("name")] = given.get(arg.get("name"), substitute(
                arg.get("default", ""), {**args, **given}))
    for node in root.iter("node"):
        pkg, exe = node.get("pkg"), node.get("exec")
        cond = node.get("if")
        if cond and "$(eval" not in cond and substitute(cond, args) != "true":
            continue
        if cond and "$(eval" in cond:
            m = re.search(r"'\$\(var (\w+)\)' == '(\w+)'", cond)
            assert m, f"unchecked condition {cond}"
            if args[m.group(1)] != m.group(2):
                continue
        seen.append(exe)
        names = EXTERNAL.get((pkg, exe))
        if names is None:
            assert (SRC / pkg / "package.xml").exists(), f"{path.name}: no package {pkg}"
            names = declared(pkg, exe)
        for param in node.findall("param"):
            if param.get("from"):
                file = share_file(substitute(param.get("from"), args))
                assert file.exists(), f"{path.name}: no parameter file {file}"
                data = yaml.safe_load(file.read_text())
                ns, name = node.get("namespace", ""), node.get("name", exe)
                key = f"/{ns}/{name}" if ns else f"/{name}"
                assert key in data, f"{file.name} has no section {key} for {exe}"
                unknown = set(data[key]["ros__parameters"]) - names
                assert not unknown, f"{file.name} {key}: {exe} declares no {sorted(unknown)}"
                for section in data:  # every section is for a node some launch file starts
                    assert section.rsplit("/", 1)[-1] in ALL_NODES, f"{file.name}: {section}"
            else:
                assert param.get("name") in names, \
                    f"{path.name}: {exe} declares no parameter {param.get('name')}"
                value = substitute(param.get("value", ""), args)
                for cat in re.findall(r"cat (\S+?)'?\)", value):
                    assert share_file(cat).exists(), f"{path.name}: no file {cat}"
        for text in re.findall(r"-d (\S+)", substitute(node.get("args", ""), args)):
            assert share_file(text).exists(), f"no RViz config {text}"
    for inc in root.iter("include"):
        target = share_file(substitute(inc.get("file"), args))
        assert target.exists(), f"{path.name}: includes a missing {target}"
        sub = {a.get("name"): substitute(a.get("value"), args) for a in inc.findall("arg")}
        check_launch(target, sub, seen)


ALL_NODES = {n.get("name") for f in LAUNCH for n in ET.parse(f).getroot().iter("node")}


def test_there_are_launch_files_for_mock_and_hardware():
    assert {p.name for p in LAUNCH} >= {"mock.launch.xml", "hardware.launch.xml"}


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", ["mock.launch.xml", "hardware.launch.xml"])
def test_launch_file_names_only_what_exists(name, variant):
    for force in ("false", "true"):
        seen: list[str] = []
        check_launch(PKG / "launch" / name, {"variant": variant, "rviz": "true",
                                             "force": force}, seen)
        driver = "mock_driver" if name.startswith("mock") else "dynamixel_driver"
        assert driver in seen and "robot_state_publisher" in seen and "ik_service" in seen
        assert ("pmac_rail_driver" in seen) == (name.startswith("hardware")
                                                and variant == "rail_arm")
        assert ("hybrid_force" in seen) == (force == "true")


def test_the_checker_catches_an_undeclared_parameter(tmp_path):
    bad = tmp_path / "bad.launch.xml"
    bad.write_text('<launch><node pkg="hyperarm_ik" exec="fk_node" name="fk_node">'
                   '<param name="no_such_parameter" value="1"/></node></launch>')
    with pytest.raises(AssertionError, match="no_such_parameter"):
        check_launch(bad, {}, [])
    bad.write_text('<launch><node pkg="hyperarm_ik" exec="no_such_exe"/></launch>')
    with pytest.raises(AssertionError, match="no executable"):
        check_launch(bad, {}, [])
