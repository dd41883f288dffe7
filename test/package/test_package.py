"""The package as installed: console scripts, launch files, share/ contents, colcon."""

from __future__ import annotations

import ast
import importlib.util
import os
import shutil
import subprocess
import sys
import types
from pathlib import Path
from typing import ClassVar

import pytest

from eit_skin.ros.node_graph import NODE_ENVIRONMENT
from eit_skin.ros.parameters import launch_arguments


def console_scripts(repo: Path) -> dict[str, str]:
    """name -> 'module:function' from setup.py's entry_points literal."""
    tree = ast.parse((repo / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "entry_points":
            scripts = ast.literal_eval(node.value)["console_scripts"]
            return dict(line.replace(" ", "").split("=", 1) for line in scripts)
    raise AssertionError("setup.py has no entry_points")


def test_every_console_script_resolves(repo: Path) -> None:
    scripts = console_scripts(repo)
    assert {"eit-skin", "eit_driver", "eit_reconstruction", "eit_classifier"} <= set(scripts)
    for name, target in scripts.items():
        module_name, function = target.split(":")
        assert importlib.util.find_spec(module_name) is not None, f"{name}: no module {module_name}"
        module = importlib.import_module(module_name)
        assert callable(getattr(module, function, None)), f"{name}: {target} is not callable"


class _Recorder:
    """Stand-in for launch/launch_ros classes: records what the launch file builds."""

    def __init__(self, *args, **kwargs) -> None:
        self.args, self.kwargs = args, kwargs


class _Argument(_Recorder):
    pass


class _Node(_Recorder):
    pass


class _Opaque(_Recorder):
    pass


class _Config:
    values: ClassVar[dict[str, str]] = {}

    def __init__(self, name: str) -> None:
        self.name = name

    def perform(self, context: object) -> str:
        return _Config.values[self.name]


def _stand_in_modules() -> dict[str, types.ModuleType]:
    """Minimal launch/launch_ros: only the names our launch files use, recording calls."""
    modules = {
        name: types.ModuleType(name)
        for name in ("launch", "launch.actions", "launch.conditions", "launch.substitutions")
    }
    modules |= {name: types.ModuleType(name) for name in ("launch_ros", "launch_ros.actions")}
    modules["launch"].LaunchDescription = lambda actions: list(actions)
    modules["launch.actions"].DeclareLaunchArgument = _Argument
    modules["launch.actions"].OpaqueFunction = _Opaque
    modules["launch.actions"].LogInfo = _Recorder
    modules["launch.conditions"].IfCondition = _Recorder
    modules["launch.substitutions"].LaunchConfiguration = _Config
    modules["launch_ros.actions"].Node = _Node
    return modules


LAUNCH_FILES = ["skin_patch.launch.py", "robot_skin.launch.py"]


@pytest.mark.parametrize("launch_file", LAUNCH_FILES)
def test_launch_file_names_only_installed_executables(
    repo: Path, launch_file: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    for name, module in _stand_in_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    share = tmp_path / "share"
    monkeypatch.setitem(
        sys.modules,
        "ament_index_python.packages",
        types.SimpleNamespace(
            get_package_share_directory=lambda pkg: str(share / pkg),
            get_package_prefix=lambda pkg: str(tmp_path),  # rviz2 "installed"
            PackageNotFoundError=LookupError,
        ),
    )
    path = repo / "launch" / launch_file
    spec = importlib.util.spec_from_file_location(launch_file.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    actions = module.generate_launch_description()

    arguments = {a.args[0]: a.kwargs["default_value"] for a in actions if isinstance(a, _Argument)}
    per_parameter = set(launch_arguments())  # documented in docs/nodes.md
    assert per_parameter <= set(arguments), per_parameter - set(arguments)
    for name in set(arguments) - per_parameter:  # documented in the file's docstring
        assert f"\n  {name} " in module.__doc__, f"{launch_file}: argument {name} undocumented"
    assert "\n  <parameter> " in module.__doc__
    _Config.values = dict(arguments)
    opaque = [a for a in actions if isinstance(a, _Opaque) and "condition" not in a.kwargs]
    assert len(opaque) == 1
    nodes = opaque[0].kwargs["function"](None)
    (viewer,) = [a for a in actions if isinstance(a, _Opaque) and "condition" in a.kwargs]
    assert viewer.kwargs["condition"].args[0].name == "rviz"

    scripts = console_scripts(repo)
    assert nodes, "launch file starts no node"
    for node in nodes:
        assert node.kwargs["package"] == "eit_skin"
        assert node.kwargs["executable"] in scripts, node.kwargs["executable"]
        for params in node.kwargs["parameters"]:
            assert Path(params["patch_config"]).is_file()
        assert node.kwargs["additional_env"] == NODE_ENVIRONMENT  # as in `eit-skin run`
    (rviz,) = [a for a in viewer.kwargs["function"](None) if isinstance(a, _Node)]
    config = Path(rviz.kwargs["arguments"][1])  # generated for the launched patches
    assert rviz.kwargs["arguments"][0] == "-d" and config.suffix == ".rviz"
    assert "/arm/pressure/image_color" in config.read_text()
    namespaces = {node.kwargs["namespace"] for node in nodes}
    assert namespaces == (
        {"/arm"} if launch_file.startswith("skin") else {"/arm", "/face", "/elbow"}
    )


# CMake builds of both packages (113 s idle on 2026-11-21, issue 38; 55 s at load 15 today)
@pytest.mark.timeout(180)
@pytest.mark.slow
def test_colcon_build_installs_both_packages(repo: Path, tmp_path: Path) -> None:
    """`colcon build` at the repository root builds eit_skin_msgs and eit_skin."""
    src = tmp_path / "src"
    tracked = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard"], cwd=repo, capture_output=True, text=True
    ).stdout.split()
    for rel in tracked:
        if (repo / rel).is_file():
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(repo / rel, src / rel)
    colcon = Path(sys.executable).with_name("colcon")
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix)
    result = subprocess.run(
        [colcon, "build", "--event-handlers", "console_direct-"],
        cwd=src,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    install = src / "install"
    share = install / "eit_skin" / "share" / "eit_skin"
    for folder in ("config", "launch"):
        wanted = {p.name for p in (repo / folder).iterdir() if p.is_file()}
        assert wanted, folder
        assert wanted <= {p.name for p in (share / folder).iterdir()}, folder
    assert (share / "package.xml").is_file()
    marker = install / "eit_skin" / "share" / "ament_index" / "resource_index" / "packages"
    assert (marker / "eit_skin").is_file()
    lib = install / "eit_skin" / "lib" / "eit_skin"
    assert set(console_scripts(repo)) <= {p.name for p in lib.iterdir()}
    msgs = install / "eit_skin_msgs"
    assert list(msgs.glob("lib/python3*/site-packages/eit_skin_msgs/msg/_eit_frame.py"))
    assert (msgs / "share" / "eit_skin_msgs" / "msg" / "TouchEvent.msg").is_file()


#: Python module -> the rosdep key or ROS package that provides it (where the names differ).
MODULE_KEYS = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "numba": "python3-numba",
    "yaml": "python3-yaml",
    "serial": "python3-serial",
    "matplotlib": "python3-matplotlib",
    "PIL": "python3-pil",
    "triangle": "python3-triangle-pip",
    "mcap": "mcap-ros2-support",
    "mcap_ros2": "mcap-ros2-support",
    "ezdxf": "python3-ezdxf",
    "svg": "python3-svg.path",
    "ruamel": "python3-ruamel.yaml",
    "aiohttp": "python3-aiohttp",
    "pytest": "python3-pytest",
    "hypothesis": "python3-hypothesis",
}
#: Imported only by tests that skip without it (a cross-check peer, not on rosdep).
OPTIONAL_TEST_MODULES = {"pyeit"}
#: Imported by the package only when a patch asks for it, with a clear refusal naming the
#: package when it is missing (docs/boards.md): pyadi-iio for the CN0565 board profile.
OPTIONAL_RUNTIME_MODULES = {"adi"}


def declared(repo: Path, kinds: tuple[str, ...]) -> set[str]:
    """Dependencies of package.xml and msg/package.xml of the given tag kinds."""
    import xml.etree.ElementTree as ET

    names = set()
    for path in (repo / "package.xml", repo / "msg" / "package.xml"):
        for element in ET.parse(path).getroot():
            if element.tag in kinds:
                names.add(element.text.strip())
    return names


def imported_modules(folder: Path) -> set[str]:
    """Top-level modules imported anywhere under ``folder`` (not the standard library, not
    the repository's own packages: eit_skin, test, bench)."""
    modules = set()
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                modules |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                modules.add(node.module.split(".")[0])
    return modules - set(sys.stdlib_module_names) - {"eit_skin", "test", "bench", "__future__"}


DEPEND_TAGS = (
    "depend",
    "exec_depend",
    "build_depend",
    "buildtool_depend",
    "test_depend",
    "build_export_depend",
)


def test_every_dependency_is_a_valid_rosdep_key(repo: Path) -> None:
    """`rosdep install --from-paths . msg --ignore-src` resolves every key: each one is in the
    extract of rosdep's public key files and the Kilted distribution (test/data)."""
    import yaml

    known = yaml.safe_load((repo / "test" / "data" / "rosdep_keys.yaml").read_text())
    valid = set(known["rosdep_keys"]) | set(known["ros_packages"]) | {"eit_skin_msgs"}
    unknown = declared(repo, DEPEND_TAGS) - valid
    assert not unknown, f"not rosdep keys nor Kilted packages: {sorted(unknown)}"


def test_every_imported_module_is_declared(repo: Path) -> None:
    """What the package imports is an exec_depend; what only the tests import, a test_depend."""
    runtime = declared(repo, ("depend", "exec_depend"))
    tests = runtime | declared(repo, ("test_depend",))
    missing = {
        module
        for module in imported_modules(repo / "eit_skin") - OPTIONAL_RUNTIME_MODULES
        if MODULE_KEYS.get(module, module) not in runtime
    }
    assert not missing, f"imported by eit_skin, not an exec_depend: {sorted(missing)}"
    missing = {
        module
        for module in imported_modules(repo / "test") - OPTIONAL_TEST_MODULES
        if MODULE_KEYS.get(module, module) not in tests
    }
    assert not missing, f"imported by the tests, not declared: {sorted(missing)}"
