"""`eit-skin run`: the whole node graph as separate processes over DDS, like ros2 launch."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest
from PIL import Image as PilImage

from eit_skin.cli.run import waiting_for_readers
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.ros.bringup import find_executable
from eit_skin.ros.node_graph import patch_nodes
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.topics import patch_topics
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros


@pytest.fixture(scope="module")
def env(tmp_path_factory) -> dict[str, str]:
    cache = tmp_path_factory.mktemp("cache")
    for name in ("arm", "face", "elbow"):
        for layer in load_patch(config_path(name)).layers:
            LayerImager.build(layer, cache_dir=cache)
    return dict(os.environ, EIT_SKIN_CACHE=str(cache))


def run(args: list[str], env: dict[str, str], timeout: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(find_executable("eit-skin")), "run", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


@pytest.fixture(scope="module")
def all_patches_one_push(tmp_path_factory, env) -> tuple[subprocess.CompletedProcess, Path]:
    """``eit-skin run --all --scenario push`` with no duration, once for the two tests below
    (one run of nine node processes instead of a face run and an all-patches run): its
    result and output folder."""
    out = tmp_path_factory.mktemp("all") / "out"
    # a ceiling, returned from as soon as the run ends: nine processes start on two cores
    result = run(["--all", "--scenario", "push", "--out", str(out)], env, timeout=600)
    return result, out


# nine node processes and a push played on each patch: ~25 s idle
@pytest.mark.timeout(120)
def test_one_pass_of_a_push_prints_the_touch_and_saves_pictures(all_patches_one_push) -> None:
    """No duration given: the run stops by itself after one pass of the script, exit 0."""
    result, out = all_patches_one_push
    assert result.returncode == 0, result.stdout + result.stderr
    starts = re.findall(r"\] face\s+(\w+)\s+START", result.stdout)
    ends = re.findall(r"\] face\s+(\w+)\s+END", result.stdout)
    assert starts and ends, result.stdout
    assert ends[-1] == "PUSH", result.stdout
    assert "face:" in result.stdout and "touches: push" in result.stdout
    written = re.search(r"wrote .*face\.gif \((\d+) frames\)", result.stdout)
    assert written and int(written.group(1)) >= 5  # 5 frames/s while images flow
    assert PilImage.open(out / "face.gif").n_frames >= 3  # identical frames are merged
    snapshots = list(out.glob("face_*_push.png"))
    assert snapshots and PilImage.open(snapshots[0]).size[0] > 100
    logs = {p.name for p in (out / "logs").iterdir() if p.name.startswith("face_")}
    assert logs == {"face_eit_driver.log", "face_eit_reconstruction.log", "face_eit_classifier.log"}


def test_all_patches_at_once(all_patches_one_push) -> None:
    result, out = all_patches_one_push
    assert result.returncode == 0, result.stdout + result.stderr
    for name in ("arm", "face", "elbow"):
        match = re.search(rf"^{name}: (\d+) images", result.stdout, re.MULTILINE)
        # nine processes share two cores here: every patch must image, at whatever rate
        assert match and int(match.group(1)) > 0, result.stdout
        assert (out / f"{name}.gif").is_file()
    assert len(list((out / "logs").iterdir())) == 9


def test_bad_arguments_fail_clearly(tmp_path, env) -> None:
    result = run(["--all", "--port", "/dev/null", "--out", str(tmp_path)], env, timeout=30)
    assert result.returncode == 2 and "--all" in result.stderr
    result = run(["--patch", str(tmp_path / "missing.yaml"), "--out", str(tmp_path)], env, 30)
    assert result.returncode == 2 and "missing.yaml" in result.stderr


def test_the_runs_simulated_driver_waits_for_every_reader_of_its_frames(tmp_path, env) -> None:
    """The driver of `eit-skin run` holds its script until all who read the pressure
    layer's frames listen: the patch's own nodes that subscribe to them (counted here on
    the real graph) and the run's monitor. One fewer let two of them start the script
    without the third (a reconstruction that took its reference during the first push)."""
    specs = patch_nodes("face", namespace="wait_face", sim=True, scenario="push", loop=False)
    specs = [waiting_for_readers(spec, specs) for spec in specs]
    driver = next(spec for spec in specs if spec.executable == "eit_driver")
    topic = patch_topics(load_patch(config_path("face")), "/wait_face").layers["pressure"].frames
    probe = Probe("wait_probe")
    logs, nodes = [], []
    try:
        for spec in specs:
            if spec.executable != "eit_driver":
                log = tmp_path / f"{spec.executable}.log"
                params = {**spec.parameters, "cache_dir": env["EIT_SKIN_CACHE"]}
                nodes.append(start_node(spec.executable, spec.namespace, params, log))
                logs.append(log)
        readers = len(nodes)  # each subscribes to the frames once
        assert probe.spin_until(lambda: probe.node.count_subscribers(topic) >= readers, EVENT_S), (
            "\n".join(log.read_text() for log in logs)
        )
        assert probe.node.count_subscribers(topic) == readers
        assert driver.parameters["wait_for_subscribers"] == readers + 1  # and the monitor
    finally:
        for node in nodes:
            assert stop_node(node) == 0
        probe.close()
