"""A patch on several boards: the arm's two layers on two pseudo-terminal fake boards.

Real node processes from the node graph (what `eit-skin run` and the launch files start) over
real DDS: one eit_driver per board, each serving its layer with its own device clock; the
reconstruction images both layers, the classifier pairs their images although the two
boards' stamps differ, and every diagnostic is truthful. A layer left without a board is
refused up front, by the graph and by the driver itself.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import EitFrame
from sensor_msgs.msg import Image

from eit_skin.hardware.fake_device import FakeDevice, WireHeader
from eit_skin.hardware.sources import pattern_id
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.ros.bringup import RunningNode, find_executable, start, stop
from eit_skin.ros.node_graph import parse_ports, patch_nodes, read_ports_file
from eit_skin.ros.probe import Probe, start_node
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics
from eit_skin.sim.simulator import SkinSimulator

pytestmark = [pytest.mark.ros, pytest.mark.slow]

ARM = load_patch(config_path("arm"))
RATE_HZ = 50.0
STARTUP_S = 300.0
"""Ceiling of every wait below (each returns as soon as its event happens)."""


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    cache = tmp_path_factory.mktemp("cache")
    for layer in ARM.layers:
        LayerImager.build(layer, cache_dir=cache)
    return cache


def boards(tmp_path: Path) -> tuple[list[FakeDevice], dict[str, str]]:
    """One fake board per arm layer, each looping the simulated push on its own clock."""
    simulator = SkinSimulator(ARM, "push", rate_hz=RATE_HZ, seed=0)
    n = simulator.n_frames
    devices, ports = [], {}
    for layer in ARM.layers:
        device = FakeDevice(
            lambda i, name=layer.name: simulator.frame(i % n)[name].voltages_v,
            RATE_HZ,
            header=WireHeader(
                n_electrodes=layer.n_electrodes,
                current_a=layer.current_a,
                pattern_id=pattern_id(layer),
                pattern_param=layer.protocol.drive_skip,
            ),
        )
        device.open()
        link = tmp_path / f"eit_skin_arm_{layer.name}"
        device.link(link)
        devices.append(device)
        ports[layer.name] = str(link)
    return devices, ports


def statuses(probe: Probe, node: str) -> list:
    return [s for _, m in probe.messages[DIAGNOSTICS] for s in m.status if node in s.name]


def values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_arm_on_two_boards_images_both_layers(
    tmp_path: Path, cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("EIT_SKIN_CACHE", str(cache))
    devices, ports = boards(tmp_path)
    # as given on the command line: ports:=pressure=...,stretch=...
    text = ",".join(f"{layer}={device}" for layer, device in ports.items())
    specs = patch_nodes("arm", "/arm2", sim=False, ports=parse_ports(text))
    drivers = [s for s in specs if s.executable == "eit_driver"]
    assert [(s.name, s.parameters["layer"], s.parameters["port"]) for s in drivers] == [
        (f"eit_driver_{layer}", layer, port) for layer, port in ports.items()
    ]
    assert [s.parameters["publish_tf"] for s in drivers] == [True, False]
    topics = patch_topics(ARM, "/arm2")
    probe = Probe("multi_board_probe")
    for layer in topics.layers.values():
        probe.subscribe(EitFrame, layer.frames)
        probe.subscribe(Image, layer.image)
    probe.subscribe(DiagnosticArray, DIAGNOSTICS, 50)
    nodes: list[RunningNode] = []
    try:
        nodes = [start(spec, tmp_path / "logs") for spec in specs]
        for device in devices:
            device.start()

        def healthy() -> bool:
            """Images on both layers and, after them, every node's diagnostics OK."""
            if any(n.process.poll() is not None for n in nodes):
                return True
            if not all(probe.messages[t.image] for t in topics.layers.values()):
                return False
            latest = {}
            for status in statuses(probe, "/arm2/"):
                latest[status.name] = status
            names = set(latest)
            wanted = {f"/arm2/eit_driver_{layer}: {layer}" for layer in ports}
            wanted |= {f"/arm2/eit_reconstruction: {layer}" for layer in ports}
            return wanted <= names and all(latest[n].level[0] == 0 for n in wanted)

        ok = probe.spin_until(healthy, STARTUP_S)
        logs = {n.label: n.log_path.read_text()[-2000:] for n in nodes}
        assert ok and all(n.process.poll() is None for n in nodes), logs
        for layer, port in ports.items():
            # each layer's frames came from its own board, stamped by its own device clock
            frames = [m for _, m in probe.messages[topics.layers[layer].frames]]
            assert frames and {m.layer for m in frames} == {layer}
            status = statuses(probe, f"eit_driver_{layer}")[-1]
            assert values(status)["port"] == port and values(status)["state"] == "connected"
            assert probe.messages[topics.layers[layer].image]
        # the classifier hears both layers: pressure images paired with stretch images of
        # the other board's nearest stamp
        assert probe.spin_until(
            lambda: (
                bool(statuses(probe, "/arm2/eit_classifier"))
                and int(values(statuses(probe, "/arm2/eit_classifier")[-1])["images"])
                - int(values(statuses(probe, "/arm2/eit_classifier")[-1])["unpaired"])
                >= 20
            ),
            STARTUP_S,
        ), statuses(probe, "/arm2/eit_classifier")[-1:]
        pressure = {
            m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            for _, m in probe.messages[topics.layers["pressure"].frames]
        }
        stretch = {
            m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            for _, m in probe.messages[topics.layers["stretch"].frames]
        }
        assert len(pressure & stretch) < len(pressure) / 2  # two clocks: stamps differ
    finally:
        codes = stop(nodes)
        for device in devices:
            device.stop()
            device.unplug()
        probe.close()
    assert set(codes.values()) == {0}, codes


def test_a_layer_without_a_board_is_refused(tmp_path: Path) -> None:
    """One port for the two-layer arm: no silent stretch layer, a refusal naming the fix."""
    with pytest.raises(ValueError, match=r"pressure, stretch.*ports:=pressure=/dev/"):
        patch_nodes("arm", port="/dev/ttyACM0", sim=False)
    with pytest.raises(ValueError, match=r"no port for layer.*stretch"):
        patch_nodes("arm", ports={"pressure": "/dev/ttyACM0"}, sim=False)
    with pytest.raises(ValueError, match=r"no layer \['sleeve'\]"):
        patch_nodes("arm", ports={"pressure": "/a", "stretch": "/b", "sleeve": "/c"}, sim=False)
    with pytest.raises(ValueError, match="not LAYER=DEVICE"):
        parse_ports("pressure:/dev/ttyACM0")
    # the driver alone, with a port and no layer, refuses too (exit 2)
    log = tmp_path / "driver.log"
    driver = start_node("eit_driver", "/arm_one_port", {"patch_config": "arm", "port": "/a"}, log)
    try:
        assert driver.wait(STARTUP_S) == 2, log.read_text()
    except subprocess.TimeoutExpired:
        driver.kill()
        raise
    assert "has layers pressure, stretch, one board each; set layer" in log.read_text()


def test_shipped_ports_file_gives_every_layer_a_board(tmp_path: Path) -> None:
    for name in ("arm", "face", "elbow"):
        ports = read_ports_file("", name)  # the shipped config/ports.yaml
        assert set(ports) == set(load_patch(config_path(name)).layer_names), name
    bad = tmp_path / "ports.yaml"
    bad.write_text("arm:\n  pressure: /dev/a\n  stretch: /dev/b\n")
    with pytest.raises(ValueError, match=f"{bad}: face: no ports for patch 'face'"):
        read_ports_file(str(bad), "face")


def test_eit_skin_run_on_two_boards(tmp_path: Path, cache: Path) -> None:
    """`eit-skin run --ports`: one driver per board, images and a clean exit after --duration."""
    devices, ports = boards(tmp_path)
    ports_file = tmp_path / "ports.yaml"
    ports_file.write_text("arm:\n" + "".join(f"  {k}: {v}\n" for k, v in ports.items()))
    out = tmp_path / "out"
    for device in devices:
        device.start()
    try:
        result = subprocess.run(
            [
                *(str(find_executable("eit-skin")), "run", "--patch", "arm"),
                *("--ports-file", str(ports_file), "--duration", "5", "--out", str(out)),
            ],
            capture_output=True,
            text=True,
            timeout=STARTUP_S,
            env=dict(os.environ, EIT_SKIN_CACHE=str(cache)),
        )
    finally:
        for device in devices:
            device.stop()
            device.unplug()
    assert result.returncode == 0, result.stdout + result.stderr
    match = re.search(r"^arm: (\d+) images", result.stdout, re.MULTILINE)
    assert match and int(match.group(1)) > 0, result.stdout
    logs = {p.name for p in (out / "logs").iterdir()}
    assert {"arm_eit_driver_pressure.log", "arm_eit_driver_stretch.log"} <= logs, logs
    for layer, port in ports.items():
        assert port in (out / "logs" / f"arm_eit_driver_{layer}.log").read_text()
