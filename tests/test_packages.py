"""The ROS 2 packages (issue 24): the driver (ros/al5d) and a package of `al5d moveit`,
built by colcon in a fresh workspace as a ROS user builds them, beside the venv's ament.

What needs a ROS install (ros2 launch, move_group, the controller manager) cannot run
here: the launch files are compiled and what they name is looked up in the install.
"""

from __future__ import annotations

import ast
import os
import re
import stat
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from al5d.app.moveit import Arm, moveit_files_of_arms, write_files, write_moveit_config
from al5d.arm.config import DEFAULT_CONFIG, load_config, with_changes
from al5d.ros import params

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
PACKAGES = ("al5d", "al5d_moveit_config", "al5d_arms_moveit_config")
EXECUTABLES = ("al5d", "server", "web", "emulator")
XML = (".xml", ".srdf", ".urdf", ".xacro")
YAML = (".yaml", ".rviz", ".setup_assistant")
#: The message packages the Makefile builds into the venv, ours first.
PACKAGES_BUILT = ("al5d_interfaces", "control_msgs", "tf2_msgs")


def colcon(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {
        **os.environ,
        # The venv is the underlay, as a sourced ROS install would be (the Makefile
        # builds al5d_interfaces into it the same way).
        "AMENT_PREFIX_PATH": sys.prefix,
        "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
        # No user's colcon defaults or mixins.
        "COLCON_HOME": str(cwd / ".colcon"),
    }
    return subprocess.run(
        [str(BIN / "colcon"), *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A workspace with the driver's package (a link into this repository, as a user links
    a clone) and two packages freshly written by `al5d moveit`, one arm's and two arms'
    (`--arms`), built; its install/."""
    ws = tmp_path_factory.mktemp("ws")
    (ws / "src").mkdir()
    (ws / "src" / "al5d").symlink_to(REPO / "ros" / "al5d")
    write_moveit_config(ws / "src" / "al5d_moveit_config", load_config(None), "left")
    arms = [
        Arm(ns, with_changes(load_config(None), {"server.mount": {"xyz": [0.0, y, 0.0]}}))
        for ns, y in (("left", 0.3), ("right", -0.3))
    ]
    write_files(ws / "src" / PACKAGES[2], moveit_files_of_arms(arms, PACKAGES[2]))
    done = colcon(
        "build",
        "--executor",
        "sequential",
        "--cmake-args",
        "-DBUILD_TESTING=OFF",
        f"-DPython3_EXECUTABLE={sys.executable}",
        cwd=ws,
    )
    assert done.returncode == 0, (done.stdout + done.stderr)[-4000:]
    for package in PACKAGES:
        assert f"Finished <<< {package}" in done.stdout, done.stdout[-2000:]
    return ws / "install"


def share(install: Path, package: str) -> Path:
    return install / package / "share" / package


def installed_files(install: Path) -> Iterator[Path]:
    for package in PACKAGES:
        for path in share(install, package).rglob("*"):
            if path.is_file():
                yield path


def test_colcon_finds_the_repositorys_packages_and_no_others(tmp_path: Path) -> None:
    # A clone in a workspace's src/ gives these three; control_msgs and tf2_msgs (built
    # into the venv only when missing) would shadow a ROS install's real ones, and the
    # Makefile's cmake builds under build/ hold a setup.py and CMakeLists.txt of their own.
    listed = colcon("list", "--base-paths", str(REPO), cwd=tmp_path)  # its log/ there
    assert listed.returncode == 0, listed.stderr
    found = dict(line.split("\t")[0::2] for line in listed.stdout.splitlines())
    assert found == {
        "al5d": "(ros.ament_cmake)",
        "al5d_interfaces": "(ros.ament_cmake)",
        "al5d_moveit_config": "(ros.ament_cmake)",
    }, listed.stdout


def test_the_packages_are_installed_where_ros_tools_look(
    install: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from ament_index_python.packages import get_package_prefix, get_package_share_directory
    from ament_index_python.resources import get_resources

    monkeypatch.setenv("AMENT_PREFIX_PATH", os.pathsep.join(str(install / p) for p in PACKAGES))
    assert set(PACKAGES) <= set(get_resources("packages"))
    for package in PACKAGES:
        assert Path(get_package_share_directory(package)) == share(install, package)
        marker = install / package / "share" / "ament_index" / "resource_index" / "packages"
        assert (marker / package).is_file()
        manifest = ET.parse(share(install, package) / "package.xml").getroot()
        assert manifest.get("format") == "3" and manifest.findtext("name") == package
        assert manifest.findtext("export/build_type") == "ament_cmake"
        for folder in ("launch", "config"):
            assert any((share(install, package) / folder).iterdir()), f"{package}/{folder}"

    # `ros2 run al5d <exe>` looks in lib/al5d of the package's prefix.
    lib = Path(get_package_prefix("al5d")) / "lib" / "al5d"
    for name in EXECUTABLES:
        exe = lib / name
        assert exe.stat().st_mode & stat.S_IXUSR, name
        assert exe.read_text().splitlines()[0] == f"#!{sys.executable}"
    site = install / "al5d" / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}"
    package = site / "site-packages" / "al5d"
    assert (package / "data" / "al5d.yaml").read_bytes() == DEFAULT_CONFIG.read_bytes()
    assert (package / "py.typed").is_file()
    config = share(install, "al5d") / "config" / "al5d.yaml"
    assert config.read_bytes() == (REPO / "config" / "al5d.yaml").read_bytes()

    # The MoveIt package's files, installed as written (package.xml by ament itself).
    source = install.parent / "src" / "al5d_moveit_config"
    for path in source.rglob("*"):
        if path.is_file() and path.name != "CMakeLists.txt":
            installed = share(install, "al5d_moveit_config") / path.relative_to(source)
            assert installed.read_bytes() == path.read_bytes(), path


def test_the_installed_executables_run_from_the_workspace(install: Path) -> None:
    # As a user runs them after sourcing the workspace: the package comes from the
    # install space, not from the pip route's editable install.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH")}

    def run(*command: str) -> str:
        done = subprocess.run(
            ["sh", "-c", '. "$0"/setup.sh && exec "$@"', str(install), *command],
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        return done.stdout

    where = run(
        sys.executable,
        "-c",
        "import al5d, os; print(al5d.__file__, os.environ['AMENT_PREFIX_PATH'])",
    )
    module, prefixes = where.split()
    assert Path(module).is_relative_to(install / "al5d")
    assert str(install / "al5d") in prefixes.split(os.pathsep)
    lib = install / "al5d" / "lib" / "al5d"
    assert 'link name="left/base_link"' in run(str(lib / "al5d"), "urdf", "--namespace", "left")
    assert run(str(lib / "server"), "--help").startswith("usage: al5d serve")
    assert run(str(lib / "web"), "--help").startswith("usage: al5d web")
    assert run(str(lib / "emulator"), "--help").startswith("usage: al5d emulator")


def test_every_installed_xml_and_yaml_parses(install: Path) -> None:
    parsed = {"xml": 0, "yaml": 0}
    for path in installed_files(install):
        if path.name.endswith(XML):
            ET.parse(path)
            parsed["xml"] += 1
        elif path.name.endswith(YAML):
            assert yaml.safe_load(path.read_text(encoding="utf-8")) is not None, path
            parsed["yaml"] += 1
    # package.xml twice, SRDF, URDF, two xacros; three configs of the driver's share
    # counted apart: al5d.yaml, and the MoveIt package's nine YAML files and .rviz.
    assert parsed["xml"] >= 6 and parsed["yaml"] >= 10, parsed


def test_joint_limits_and_cartesian_limits_are_floats(install: Path) -> None:
    # MoveIt 2 reads these as doubles and rejects an integer (moveit/moveit2#2776).
    config = share(install, "al5d_moveit_config") / "config"
    limits = yaml.safe_load((config / "joint_limits.yaml").read_text())
    numbers = [
        limits["default_velocity_scaling_factor"],
        limits["default_acceleration_scaling_factor"],
    ]
    for joint in limits["joint_limits"].values():
        numbers += [joint["max_velocity"], joint["max_acceleration"]]
        assert isinstance(joint["has_velocity_limits"], bool)
    pilz = yaml.safe_load((config / "pilz_cartesian_limits.yaml").read_text())
    numbers += list(pilz["cartesian_limits"].values())
    initial = yaml.safe_load((config / "initial_positions.yaml").read_text())
    numbers += list(initial["initial_positions"].values())
    assert numbers and all(type(n) is float for n in numbers), numbers


#: File names a launch file may name: what it loads from a package's share directory.
_SHARED_FILE = re.compile(r"[\w.-]+\.(yaml|rviz|xacro|srdf|urdf|launch\.py)")


def _strings(tree: ast.AST) -> set[str]:
    return {
        n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
    }


def _calls(tree: ast.AST, name: str) -> list[dict[str, object]]:
    """The constant keyword arguments of every call to `name`."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == name:
            found.append(
                {k.arg: k.value.value for k in node.keywords if isinstance(k.value, ast.Constant)}
            )
    return found


def test_every_launch_file_compiles_and_names_what_is_installed(install: Path) -> None:
    launch_files = [p for p in installed_files(install) if p.name.endswith(".launch.py")]
    names = {p.name for p in launch_files}
    assert {
        "bringup.launch.py",
        "demo.launch.py",
        "move_group.launch.py",
        "rsp.launch.py",
        "moveit_rviz.launch.py",
        "spawn_controllers.launch.py",
    } <= names
    shared = {
        p.relative_to(share(install, p.parts[len(install.parts)])).as_posix()
        for p in installed_files(install)
    }
    for path in launch_files:
        text = path.read_text(encoding="utf-8")
        tree = ast.parse(text, str(path))
        compile(tree, str(path), "exec")
        functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        assert "generate_launch_description" in functions, path
        for value in _strings(tree):
            if _SHARED_FILE.fullmatch(value.rsplit("/", 1)[-1]) and "/" in value:
                assert value in shared, f"{path.name} names {value}, which is not installed"
            elif _SHARED_FILE.fullmatch(value):
                assert any(s.endswith("/" + value) for s in shared), f"{path.name}: {value}"
        for node in _calls(tree, "Node"):
            if node.get("package") == "al5d":
                exe = install / "al5d" / "lib" / "al5d" / str(node["executable"])
                assert exe.is_file(), f"{path.name} runs {exe.name}, which is not installed"


def passed_parameters(tree: ast.Module) -> set[str]:
    """The names bringup puts in its `parameters` dict: the keys it sets one by one and the
    names its comprehension takes over."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Subscript)
            and getattr(node.value, "id", None) == "parameters"
            and isinstance(node.slice, ast.Constant)
        ):
            names.add(node.slice.value)
        if isinstance(node, ast.DictComp):
            for generator in node.generators:
                if isinstance(generator.iter, ast.Tuple):
                    names |= {e.value for e in generator.iter.elts if isinstance(e, ast.Constant)}
    return names


def test_bringup_takes_the_servers_settings_as_parameters(install: Path) -> None:
    tree = ast.parse((share(install, "al5d") / "launch" / "bringup.launch.py").read_text())
    arguments = next(
        n.value
        for n in tree.body
        if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", None) == "ARGUMENTS"
    )
    assert isinstance(arguments, ast.Dict)
    declared = {k.value for k in arguments.keys if isinstance(k, ast.Constant)}
    assert {"config_file", "port", "baud", "namespace", "web"} <= declared
    # port, baud and config_file go to the node as ROS parameters of the names the server
    # declares, the namespace as the node's namespace.
    assert passed_parameters(tree) == set(params.TOP)
    (server,) = [c for c in _calls(tree, "Node") if c.get("executable") == "server"]
    assert "name" not in server
    node_call = next(
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "Node"
    )
    assert {"namespace", "parameters"} <= {k.arg for k in node_call.keywords}


def test_the_driver_package_and_the_pip_package_agree() -> None:
    manifest = ET.parse(REPO / "ros" / "al5d" / "package.xml").getroot()
    # (tomllib is 3.11's; the project runs on 3.10 too.)
    pyproject = (REPO / "pyproject.toml").read_text()
    project = dict(re.findall(r'^(version|license) = "(.+)"$', pyproject, re.M))
    assert manifest.findtext("version") == project["version"]
    assert manifest.findtext("license") == project["license"]
    depends = {d.text for d in manifest.findall("exec_depend")}
    assert {"al5d_interfaces", "rclpy", "control_msgs", "tf2_msgs", "launch_ros"} <= depends


def test_the_makefiles_message_builds_are_c_and_python_only() -> None:
    """The venv's users are Python: `make runtime` generates no C++ (it was 40 % of the
    builds' CPU time, and of `make demo`'s wait). control_msgs and tf2_msgs are built only
    where no ROS install has them, al5d_interfaces always."""
    manifests = [REPO / "build" / name / "install_manifest.txt" for name in PACKAGES_BUILT]
    built = [m for m in manifests if m.exists()]
    assert manifests[0] in built, "make runtime left no build of al5d_interfaces"
    for manifest in built:
        installed = manifest.read_text().splitlines()
        assert any(line.endswith("__rosidl_typesupport_c.so") for line in installed), (
            f"{manifest}: no C typesupport installed"
        )
        cpp = [line for line in installed if re.search(r"_cpp|\.hpp$", line)]
        assert not cpp, f"{manifest}: C++ installed: {cpp[:3]}"


def test_make_test_takes_two_workers_on_a_machine_busy_just_now() -> None:
    """`.ci/workers` counts a machine busy from what its CPU does now, not from the load
    average alone, which lags by a minute (busy loops started just before `make test`
    once got it four workers)."""
    loops = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"])
        for _ in range(os.cpu_count() or 2)
    ]
    try:
        said = subprocess.run(
            [sys.executable, str(REPO / ".ci" / "workers")],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        )
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()
    assert said.stdout.strip() == "2", said


def pypi_route_steps() -> str:
    """docs/moveit.md's steps for a workspace without a ROS install, as the page has them."""
    page = (REPO / "docs" / "moveit.md").read_text()
    section = page.split("### Without a ROS install", 1)[1]
    found = re.search(r"^```sh\n(.*?)^```$", section, re.S | re.M)
    assert found, "docs/moveit.md: no steps under 'Without a ROS install'"
    return found.group(1)


def fresh_shell(home: Path, script: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """`script` in a new bash (no profile, no rc) whose environment is a new login's: no
    venv, no AMENT_PREFIX_PATH, nothing of this test's process."""
    env = {"HOME": str(home), "PATH": "/usr/local/bin:/usr/bin:/bin", "LANG": "C.UTF-8"}
    return subprocess.run(
        ["bash", "--noprofile", "--norc", "-e", "-o", "pipefail", "-c", script],
        cwd=home,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


# A colcon build from scratch (al5d_interfaces, al5d): 41 s alone, 90 to 105 s in a full run,
# and past the suite's 120 s twice (pytest-timeout then ends the whole worker) as it grew.
@pytest.mark.timeout(600)
def test_the_pypi_route_workspace_builds_as_docs_moveit_md_says(tmp_path: Path) -> None:
    """Issue 46: the steps, word for word, with only the venv activated: colcon builds
    al5d_interfaces and al5d against the venv, install/setup.bash (and setup.zsh) exist
    and are sourced, and the installed executables run from the workspace."""
    home = tmp_path / "home"
    home.mkdir()
    (home / "al5d").symlink_to(REPO)  # the clone, where the steps say it is
    done = fresh_shell(home, pypi_route_steps())
    said = f"--- stdout\n{done.stdout[-3000:]}--- stderr\n{done.stderr[-3000:]}"
    assert done.returncode == 0, said
    for package in ("al5d_interfaces", "al5d"):
        assert f"Finished <<< {package}" in done.stdout, said
    install = home / "ws" / "install"
    assert (install / "setup.bash").is_file() and (install / "setup.zsh").is_file()
    lines = done.stdout.splitlines()
    assert lines[-2] == str(install / "al5d"), said  # the package found in the workspace
    assert lines[-1].startswith("usage: al5d serve"), said
    assert "AMENT_PREFIX_PATH" not in done.stderr, said  # colcon had no word to say of it

    # The sourced workspace chains the venv as it would chain a ROS install, so that a new
    # shell that sources only install/setup.bash finds both, and runs the executables.
    sourced = fresh_shell(
        home,
        ". ~/ws/install/setup.bash && echo $AMENT_PREFIX_PATH && "
        "~/ws/install/al5d/lib/al5d/al5d urdf --namespace left",
    )
    assert sourced.returncode == 0, sourced.stderr
    prefixes = sourced.stdout.splitlines()[0].split(os.pathsep)
    assert str(install / "al5d") in prefixes and str(REPO / ".venv") in prefixes, prefixes
    assert 'link name="left/base_link"' in sourced.stdout
    assert not sourced.stderr, sourced.stderr  # no "not found" of a chained prefix


def test_the_venvs_activate_puts_it_on_the_ament_prefix_path_and_deactivate_takes_it_off(
    tmp_path: Path,
) -> None:
    venv = REPO / ".venv"
    done = fresh_shell(
        tmp_path,
        "export AMENT_PREFIX_PATH=/opt/before\n"
        f'. "{venv}/bin/activate"\necho "$AMENT_PREFIX_PATH"\n'
        f'. "{venv}/bin/activate"\necho "$AMENT_PREFIX_PATH"\n'  # again: once on the path
        'deactivate\necho "$AMENT_PREFIX_PATH"\n'
        "unset AMENT_PREFIX_PATH\n"
        f'. "{venv}/bin/activate"\ndeactivate\necho "${{AMENT_PREFIX_PATH-unset}}"\n',
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [
        f"{venv}:/opt/before",
        f"{venv}:/opt/before",
        "/opt/before",
        "unset",
    ]
