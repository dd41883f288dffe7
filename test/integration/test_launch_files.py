"""`ros2 launch` of the shipped launch files, for real: images and touches flow per layer,
Ctrl-C (SIGINT to the launch) ends every process with exit 0 and no traceback, a mistyped
patch fails the launch with the valid ones, rviz:=true without rviz2 keeps the skin running.

The package is registered the way an ament_python install does (ament index marker,
share/eit_skin, lib/eit_skin) in a prefix under tmp_path that points at this checkout, so
no colcon build is needed. Skips where launch_ros or the ros2 CLI is not installed
(`make setup` installs them from ../shared/ros2-tools when that folder exists).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import TouchEvent
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.ros.node_graph import ROBOT_PATCHES
from eit_skin.ros.probe import Probe, lifecycle_set, stamp_ns
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics

ROS2 = Path(sys.executable).with_name("ros2")
pytestmark = [
    pytest.mark.ros,
    pytest.mark.slow,
    pytest.mark.skipif(
        not ROS2.is_file(), reason="ros2 CLI / launch_ros not installed (../shared/ros2-tools)"
    ),
]
pytest.importorskip("launch_ros", reason="launch_ros not installed (../shared/ros2-tools)")
TFMessage = pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs not installed").TFMessage

LATCHED = QoSProfile(
    depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)
STARTUP_S = 300.0
"""Ceiling of every wait for messages (each returns as soon as they arrive)."""
EXIT_S = 60.0
BAD_WORDS = ("Traceback", "FATAL", "KeyboardInterrupt", "exited with code")


@pytest.fixture(scope="module")
def env(tmp_path_factory, repo: Path) -> dict[str, str]:
    """A prefix registering eit_skin (symlinks into the checkout) and a matrix cache."""
    prefix = tmp_path_factory.mktemp("prefix")
    index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    (index / "eit_skin").write_text("")
    share = prefix / "share" / "eit_skin"
    for folder in ("launch", "config"):  # files, as ros2 launch does not enter linked folders
        (share / folder).mkdir(parents=True)
        for path in (repo / folder).iterdir():
            (share / folder / path.name).symlink_to(path)
    (share / "package.xml").symlink_to(repo / "package.xml")
    lib = prefix / "lib" / "eit_skin"
    lib.mkdir(parents=True)
    for script in ("eit_driver", "eit_reconstruction", "eit_classifier"):
        (lib / script).symlink_to(Path(sys.executable).with_name(script))
    cache = tmp_path_factory.mktemp("cache")
    for name in ROBOT_PATCHES:
        for layer in load_patch(config_path(name)).layers:
            LayerImager.build(layer, cache_dir=cache)
    return dict(
        os.environ,
        AMENT_PREFIX_PATH=f"{prefix}{os.pathsep}{sys.prefix}",
        EIT_SKIN_CACHE=str(cache),
    )


def _as_from_a_terminal() -> None:
    """In the child: SIGINT as a terminal gives it, even if this run inherited it ignored
    (a non-interactive shell ignores SIGINT in the commands it runs in the background)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def launch(args: list[str], env: dict[str, str], log: Path) -> subprocess.Popen:
    """``ros2 launch eit_skin ...`` in its own process group (so nothing outlives a test)."""
    return subprocess.Popen(
        [str(ROS2), "launch", "eit_skin", *args],
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
        env=env,
        process_group=0,
        preexec_fn=_as_from_a_terminal,
    )


def interrupt(process: subprocess.Popen, log: Path) -> str:
    """Ctrl-C: SIGINT to the launch; returns its output once it has exited.

    If it does not exit, the whole process group (the launch and every node it started) is
    killed, so a failing test leaves no orphan nodes loading the machine for the next ones.
    """
    process.send_signal(signal.SIGINT)
    try:
        process.wait(EXIT_S)
    finally:
        if process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)  # nodes left behind by an exited launch
    return log.read_text()


def watch(probe: Probe, patches: list[str]) -> list[str]:
    """Subscribe to every layer's image and the touch events; returns the topics."""
    topics = []
    for name in patches:
        names = patch_topics(load_patch(config_path(name)), f"/{name}")
        topics += [layer.image for layer in names.layers.values()]
        topics.append(names.touch_events)
        probe.subscribe(
            TouchEvent,
            names.touch_events,
            QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE),
        )
    for topic in topics:
        if not topic.endswith("touch_events"):
            probe.subscribe(Image, topic)
    return topics


def flowing(probe: Probe, topics: list[str], process: subprocess.Popen, log: Path) -> None:
    ok = probe.spin_until(
        lambda: all(probe.messages[t] for t in topics) or process.poll() is not None, STARTUP_S
    )
    missing = [t for t in topics if not probe.messages[t]]
    assert ok and not missing, f"nothing on {missing}:\n{log.read_text()[-3000:]}"


def test_patch_launch_images_touches_and_ctrl_c(tmp_path: Path, env: dict[str, str]) -> None:
    """The face patch with rviz:=true where rviz2 is not installed: the skin runs anyway; a
    params file reaches the nodes (here the driver's parent frame on /tf_static); with
    autostart:=false the driver waits for its lifecycle manager (here the ros2 CLI):
    configure and activate start the images, deactivate stops them."""
    log = tmp_path / "launch.log"
    params = tmp_path / "params.yaml"
    params.write_text("/**/eit_driver:\n  ros__parameters:\n    tf_parent_frame: from_params\n")
    probe = Probe("launch_probe")
    topics = watch(probe, ["face"])
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    args = [
        "skin_patch.launch.py",
        "patch:=face",
        "rviz:=true",
        f"params_file:={params}",
        "autostart:=false",
        "diagnostics_period_s:=0.2",
    ]
    process = launch(args, env, log)
    try:
        for transition in ("configure", "activate"):  # waits for the driver's service
            lifecycle_set("/face/eit_driver", transition, STARTUP_S)
        flowing(probe, topics, process, log)
        assert process.poll() is None
        probe.subscribe(TFMessage, "/tf_static", LATCHED)
        assert probe.spin_until(lambda: bool(probe.messages["/tf_static"]), STARTUP_S)
        (transform,) = probe.messages["/tf_static"][0][1].transforms
        assert transform.header.frame_id == "from_params"

        lifecycle_set("/face/eit_driver", "deactivate")
        deactivated_ns = time.time_ns()

        def inactive() -> int:
            return sum(
                kv.key == "lifecycle_state" and kv.value == "inactive"
                for _, msg in probe.messages[DIAGNOSTICS]
                for status in msg.status
                for kv in status.values
            )

        assert probe.spin_until(lambda: inactive() >= 3, STARTUP_S)
        images = [m for t in topics if t.endswith("/image") for _, m in probe.messages[t]]
        assert max(stamp_ns(m) for m in images) < deactivated_ns  # no frame, no image
    finally:
        output = interrupt(process, log)
        probe.close()
    assert process.returncode == 0, output
    assert not [w for w in BAD_WORDS if w in output], output
    assert "rviz2 is not installed" in output or "rviz2-" in output, output


def test_robot_launch_every_patch_flows_and_stops(tmp_path: Path, env: dict[str, str]) -> None:
    log = tmp_path / "launch.log"
    probe = Probe("launch_probe")
    topics = [t for t in watch(probe, list(ROBOT_PATCHES)) if not t.endswith("touch_events")]
    process = launch(["robot_skin.launch.py"], env, log)
    try:
        flowing(probe, topics, process, log)
    finally:
        output = interrupt(process, log)
        probe.close()
    assert process.returncode == 0, output
    assert not [w for w in BAD_WORDS if w in output], output
    assert output.count("process has finished cleanly") == 3 * len(ROBOT_PATCHES), output


def test_unknown_patch_fails_the_launch_listing_the_valid_ones(
    tmp_path: Path, env: dict[str, str]
) -> None:
    log = tmp_path / "launch.log"
    process = launch(["skin_patch.launch.py", "patch:=leg"], env, log)
    process.wait(EXIT_S)
    output = log.read_text()
    assert process.returncode != 0, output
    assert "'leg'" in output and all(name in output for name in ROBOT_PATCHES), output


def test_arm_on_two_boards_through_the_launch_file(tmp_path: Path, env: dict[str, str]) -> None:
    """ports:= starts one driver per pseudo-terminal board: both layers image; a node
    parameter given as a launch argument (tf_parent_frame:=) reaches the driver."""
    from eit_skin.hardware.fake_device import FakeDevice, WireHeader
    from eit_skin.hardware.sources import pattern_id
    from eit_skin.sim.simulator import SkinSimulator

    arm = load_patch(config_path("arm"))
    simulator = SkinSimulator(arm, "push", rate_hz=50.0, seed=0)
    devices, ports = [], []
    for layer in arm.layers:
        device = FakeDevice(
            lambda i, name=layer.name: simulator.frame(i % simulator.n_frames)[name].voltages_v,
            50.0,
            header=WireHeader(
                n_electrodes=layer.n_electrodes,
                current_a=layer.current_a,
                pattern_id=pattern_id(layer),
                pattern_param=layer.protocol.drive_skip,
            ),
        )
        device.open()
        device.link(tmp_path / f"board_{layer.name}")
        device.start()
        devices.append(device)
        ports.append(f"{layer.name}={tmp_path / f'board_{layer.name}'}")
    log = tmp_path / "launch.log"
    probe = Probe("launch_boards_probe")
    topics = [t for t in watch(probe, ["arm"]) if not t.endswith("touch_events")]
    args = ["skin_patch.launch.py", "patch:=arm", f"ports:={','.join(ports)}"]
    process = launch([*args, "tf_parent_frame:=from_arg"], env, log)
    try:
        flowing(probe, topics, process, log)
        probe.subscribe(TFMessage, "/tf_static", LATCHED)
        assert probe.spin_until(lambda: bool(probe.messages["/tf_static"]), STARTUP_S)
        (transform,) = probe.messages["/tf_static"][0][1].transforms
        assert transform.header.frame_id == "from_arg"
    finally:
        output = interrupt(process, log)
        probe.close()
        for device in devices:
            device.stop()
            device.unplug()
    assert process.returncode == 0, output
    assert not [w for w in BAD_WORDS if w in output], output
    assert "eit_driver_pressure" in output and "eit_driver_stretch" in output, output


def test_one_port_for_two_layers_fails_the_launch(tmp_path: Path, env: dict[str, str]) -> None:
    log = tmp_path / "launch.log"
    process = launch(["skin_patch.launch.py", "patch:=arm", "port:=/dev/ttyACM0"], env, log)
    process.wait(EXIT_S)
    output = log.read_text()
    assert process.returncode != 0, output
    assert "ports:=pressure=/dev/...,stretch=/dev/..." in output, output
