"""Ctrl-C and SIGTERM end every node and `eit-skin run` cleanly: exit 0, no traceback.

Real node processes over real DDS, signalled at a random moment after images flow: a race
that shows in one run out of three (a KeyboardInterrupt inside a callback, the serial or
simulator source publishing after shutdown) shows here with near certainty.
"""

from __future__ import annotations

import contextlib
import os
import random
import select
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
from sensor_msgs.msg import Image

from eit_skin.io.mcap import read_mcap_frames
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.resources import config_path
from eit_skin.ros.bringup import RunningNode, find_executable, start
from eit_skin.ros.node_graph import patch_nodes
from eit_skin.ros.probe import Probe
from eit_skin.ros.topics import patch_topics

pytestmark = [pytest.mark.ros, pytest.mark.slow]

STARTUP_S = 300.0
"""Ceiling of the wait for the first image (returns as soon as it arrives)."""
EXIT_S = 30.0
"""Ceiling of the wait for a signalled process to exit."""
RUNS = 10
BATCH = 5
BAD_WORDS = ("Traceback", "FATAL", "KeyboardInterrupt", "ExternalShutdownException")


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    cache = tmp_path_factory.mktemp("cache")
    for layer in load_patch(config_path("face")).layers:
        LayerImager.build(layer, cache_dir=cache)
    return cache


@pytest.fixture
def env_cache(cache: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("EIT_SKIN_CACHE", str(cache))
    return cache


def _image_topic(namespace: str) -> str:
    topics = patch_topics(load_patch(config_path("face")), namespace)
    return next(iter(topics.layers.values())).image


def _wait_for_image(probe: Probe, topics: list[str], nodes: list[subprocess.Popen]) -> None:
    def ready() -> bool:
        return all(probe.messages[t] for t in topics) or any(p.poll() is not None for p in nodes)

    probe.spin_until(ready, STARTUP_S)
    missing = [t for t in topics if not probe.messages[t]]
    assert not missing, f"no image on {missing} before a node exited or the ceiling"


def _clean(log: str) -> bool:
    return not any(word in log for word in BAD_WORDS)


def _start_face_run(out: Path, probe: Probe, output: int) -> tuple[subprocess.Popen, str]:
    """`eit-skin run --patch face` with its stdout+stderr to ``output``; the probe watches
    its image topic (returned). An hour's ``--duration``: the run never ends by itself
    (one script pass could end while a slow machine still starts the test's probe), so the
    signal always finds its nodes running."""
    topic = _image_topic("/face")
    probe.subscribe(Image, topic)
    command = [str(find_executable("eit-skin")), "run", "--patch", "face", "--out", str(out)]
    run = subprocess.Popen(
        [*command, "--duration", "3600"],
        stdout=output,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ),
    )
    return run, topic


def _exit_code(node: RunningNode) -> int:
    """The signalled node's exit code; a node still running after :data:`EXIT_S` fails the
    test with what it was doing: each thread's kernel state and, from its faulthandler
    (SIGUSR1, which needs no GIL), every Python thread's stack, read from its log."""
    try:
        return node.process.wait(EXIT_S)
    except subprocess.TimeoutExpired:
        threads = _threads_of(node.process.pid)
        node.process.send_signal(signal.SIGUSR1)
        deadline = time.monotonic() + 5.0  # until the dump is in the log (or 5 s)
        while "Thread 0x" not in node.log_path.read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        pytest.fail(
            f"{node.label} still running {EXIT_S:.0f} s after its signal:\n{threads}\n"
            f"{node.log_path.read_text()[-6000:]}"
        )


def _children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid``."""
    found = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True)
    return [int(child) for child in found.stdout.split()]


# 10 graphs of 3 node processes, started 5 at a time: ~60 s idle (264 s at load 15 on 2 cores)
@pytest.mark.timeout(300)
def test_every_node_ends_cleanly_on_sigint_and_sigterm(tmp_path: Path, env_cache: Path) -> None:
    """10 graphs (2 batches of 5 at once, to save start-up time), each signalled at its own
    random moment 0-1.5 s after images flow: SIGINT twice (a terminal's Ctrl-C plus
    ros2 launch's own SIGINT) or SIGTERM. Every node exits 0 without a traceback and the
    driver's recording is readable."""
    rng = random.Random(15)
    probe = Probe("shutdown_probe")
    try:
        for batch in range(RUNS // BATCH):
            graphs: dict[int, list[RunningNode]] = {}
            try:
                for run in range(batch * BATCH, (batch + 1) * BATCH):
                    driver, *others = patch_nodes("face", namespace=f"/face{run}")
                    recording = {**driver.parameters, "record_path": str(tmp_path / f"{run}.mcap")}
                    specs = [replace(driver, parameters=recording), *others]
                    probe.subscribe(Image, _image_topic(f"/face{run}"))
                    graphs[run] = [start(spec, tmp_path / f"logs{run}") for spec in specs]
                processes = [n.process for nodes in graphs.values() for n in nodes]
                _wait_for_image(probe, [_image_topic(f"/face{r}") for r in graphs], processes)
                moments = sorted((rng.uniform(0.0, 1.5), run) for run in graphs)
                elapsed = 0.0
                for moment, run in moments:
                    probe.spin_for(moment - elapsed)  # the random moment, not a wait
                    elapsed = moment
                    signals = [signal.SIGINT] * 2 if run % 2 == 0 else [signal.SIGTERM]
                    for sig in signals:
                        for node in graphs[run]:
                            node.process.send_signal(sig)
                codes = {
                    node.label: _exit_code(node) for nodes in graphs.values() for node in nodes
                }
            finally:
                for nodes in graphs.values():
                    for node in nodes:
                        if node.process.poll() is None:
                            node.process.kill()
                            node.process.wait()
            logs = {n.label: n.log_path.read_text() for nodes in graphs.values() for n in nodes}
            assert codes == dict.fromkeys(codes, 0), (codes, logs)
            dirty = {label: log for label, log in logs.items() if not _clean(log)}
            assert not dirty, dirty
            for run in graphs:
                frames = sum(1 for _ in read_mcap_frames(tmp_path / f"{run}.mcap"))
                assert frames > 0, f"run {run}: empty or unreadable recording"
    finally:
        probe.close()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_eit_skin_run_stops_its_nodes_on_a_signal(
    tmp_path: Path, env_cache: Path, sig: signal.Signals
) -> None:
    """`eit-skin run` alone signalled (a service manager's SIGTERM, or kill -INT): it stops
    every node it started, writes its pictures and exits 0."""
    out = tmp_path / "out"
    probe = Probe("run_probe")
    run, topic = _start_face_run(out, probe, subprocess.PIPE)
    try:
        _wait_for_image(probe, [topic], [run])
        children = _children(run.pid)
        assert len(children) == 3, children
        run.send_signal(sig)
        output, _ = run.communicate(timeout=EXIT_S)
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
        probe.close()
    assert run.returncode == 0, output
    assert _clean(output), output
    assert "face:" in output and (out / "face.gif").is_file(), output
    assert not [pid for pid in children if Path(f"/proc/{pid}").exists()]
    for log in (out / "logs").iterdir():
        assert _clean(log.read_text()), log.read_text()


def _threads_of(pid: int) -> str:
    """State and kernel wait channel of each thread of ``pid`` (why it has not ended)."""
    lines = []
    for task in sorted(Path(f"/proc/{pid}/task").glob("*")):
        with contextlib.suppress(OSError):
            stat = (task / "stat").read_text()
            name, state = stat[stat.index("(") + 1 : stat.rindex(")")], stat.split(") ")[1][0]
            lines.append(f"{task.name} {name} {state} {(task / 'wchan').read_text()}")
    return "\n".join(lines) or f"no /proc/{pid}/task"


def test_a_killed_eit_skin_run_leaves_no_node_behind(tmp_path: Path, env_cache: Path) -> None:
    """`eit-skin run` killed outright (SIGKILL, the OOM killer): its nodes get SIGTERM from
    the kernel, stop cleanly (exit 0 by their own handling) and close their recordings."""
    probe = Probe("killed_run_probe")
    run, topic = _start_face_run(tmp_path, probe, subprocess.DEVNULL)
    children: list[int] = []
    try:
        _wait_for_image(probe, [topic], [run])
        children = _children(run.pid)
        assert len(children) == 3, children
        pidfds = [os.pidfd_open(pid) for pid in children]
        run.kill()
        run.wait()
        for pid, fd in zip(children, pidfds, strict=True):
            # readable when that process has ended (not our child: no wait())
            ended = select.select([fd], [], [], EXIT_S)[0]
            assert ended, f"a node outlived its killed starter:\n{_threads_of(pid)}"
            os.close(fd)
    finally:
        for pid in children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        probe.close()
    for log in (tmp_path / "logs").iterdir():
        text = log.read_text()
        assert _clean(text), text


@pytest.mark.parametrize("executable", ["eit_driver", "eit_reconstruction", "eit_classifier"])
def test_sigint_while_the_node_still_imports_is_quiet(tmp_path: Path, executable: str) -> None:
    """Ctrl-C in the first second, while the process still imports rclpy and numpy: exit 0,
    no traceback. ``python -v`` reports each import as it happens; the signal goes out on
    the report of rclpy's first module, so it lands in the middle of the imports."""
    script = find_executable(executable)
    command = [sys.executable, "-v", str(script), "--ros-args", "-p", "patch_config:=face"]
    process = subprocess.Popen(
        command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=dict(os.environ)
    )
    seen = []
    try:
        for line in process.stderr:
            seen.append(line)
            if line.startswith("import 'rclpy"):
                process.send_signal(signal.SIGINT)
                break
        output = "".join(seen) + process.communicate(timeout=EXIT_S)[1]
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert any(line.startswith("import 'rclpy") for line in seen), "".join(seen[-20:])
    assert process.returncode == 0, output[-3000:]
    assert _clean(output), output[-3000:]
