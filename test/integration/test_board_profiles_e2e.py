"""Every board profile end to end: an emulated board on a pty -> eit_driver -> eit_reconstruction.

Three real boards' byte formats at once (OpenEIT replaying the hydrogel skin, a line-printing
board with a full 16 x 16 layout replaying an Ottawa tank, a Sciospec replaying its tank), each
read by a real ``eit_driver`` process in the layer's board profile and imaged by a real
``eit_reconstruction``. Checked: the driver publishes exactly the numbers a correct host
decodes from each frame the board sent, none lost once streaming; the node's images equal
``eit-skin reconstruct`` of the driver's own recording, bit for bit; and a board that answers
in another format gives an ERROR diagnostic naming the port, the profile and what it saw.

Every board first repeats the recording's reference frame until every node reports its
reference captured, then plays the recording: whichever of the first frames the node
captured (best-effort DDS may lose some while it matches), its reference is the one the
offline command captures from the recording's first frames.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from eit_skin_msgs.msg import EitFrame
from sensor_msgs.msg import Image

from eit_skin.cli.main import main
from eit_skin.hardware.board_emulators import LineFormat, LinesEmulator, OpenEITEmulator
from eit_skin.hardware.sciospec_emulator import SciospecEmulator
from eit_skin.io.mcap import read_mcap_frames
from eit_skin.io.npz import load_frames_npz
from eit_skin.patch.loading import load_patch
from eit_skin.patch.protocol import build_protocol
from eit_skin.pipeline.builder import LayerImager
from eit_skin.ros.probe import Probe, stamp_ns, start_node, stop_node
from eit_skin.ros.topics import patch_topics
from test.support.patience import EVENT_S

pytestmark = pytest.mark.ros

VARIED = 20  # frames of the recording after the reference frames
REFERENCE_FRAMES = 5
RATE_HZ = 20.0

BOARDS = {
    # name: (recording, device section, protocol override, emulator class, emulator options)
    "openeit": ("hydrogel_ohmc16", {"profile": "openeit"}, None, OpenEITEmulator, {}),
    "lines": (
        "ottawa_ph1",
        {"profile": "lines", "separators": ";"},
        {"drive": "adjacent", "measure": "adjacent", "layout": "full", "sign": -1},
        LinesEmulator,
        {"line_format": LineFormat(separator=";", label="frame", line_ending="\r\n")},
    ),
    "sciospec": (
        "sciospec_adjacent",
        {"profile": "sciospec", "frame_rate_hz": RATE_HZ, "first_channel": 1},
        None,
        SciospecEmulator,
        {},
    ),
}


def board_patch(repo, tmp_path, name: str):
    recording, device, protocol, _, _ = BOARDS[name]
    data = yaml.safe_load((repo / f"data/real/{recording}.yaml").read_text())
    data["name"] = f"board_{name}"
    data["layers"][0]["device"] = device
    if protocol is not None:
        data["layers"][0]["protocol"] = protocol
    path = tmp_path / f"board_{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture(scope="module")
def chains(repo, tmp_path_factory):
    """Per board: the patch file, the emulator, the driver's recording, the node's images."""
    tmp = tmp_path_factory.mktemp("boards")
    cache = tmp / "cache"
    go = threading.Event()
    out = {}
    for name, (recording, _, _, emulator_cls, options) in BOARDS.items():
        path = board_patch(repo, tmp, name)
        patch = load_patch(path)
        layer = patch.layers[0]
        LayerImager.build(layer, cache_dir=cache)  # once, before the node loads it
        reference, frames, _ = load_frames_npz(repo / f"data/real/{recording}.npz")
        protocol = build_protocol(layer.protocol, layer.n_electrodes)
        reference, frames = protocol.select(reference), protocol.select(frames)

        switch: dict[str, int | None] = {"at": None}

        def source(i, reference=reference, frames=frames, switch=switch):
            """The reference until ``go`` is set, then the recording (deterministic in i)."""
            if switch["at"] is None and go.is_set():
                switch["at"] = i
            if switch["at"] is None or i < switch["at"]:
                return reference
            return frames[(i - switch["at"]) % len(frames)]

        board = emulator_cls(source, protocol, rate_hz=RATE_HZ, **options)
        out[name] = {
            "switch": switch,
            "path": path,
            "patch": patch,
            "board": board,
            "mcap": tmp / f"{name}.mcap",
            "cache": cache,
        }
    probe = Probe("boards_probe")
    logs, nodes = {}, []
    try:
        for name, chain in out.items():
            topics = patch_topics(chain["patch"], f"/{chain['patch'].name}")
            chain["image_topic"] = topics.layers[chain["patch"].layers[0].name].image
            chain["frames_topic"] = topics.layers[chain["patch"].layers[0].name].frames
            probe.subscribe(Image, chain["image_topic"])
            probe.subscribe(EitFrame, chain["frames_topic"])
            logs[name] = tmp / f"{name}_recon.log"
            nodes.append(
                start_node(
                    "eit_reconstruction",
                    f"/{chain['patch'].name}",
                    {
                        "patch_config": str(chain["path"]),
                        "cache_dir": str(cache),
                        "reference_frames": REFERENCE_FRAMES,
                        "drift_time_constant_s": 0.0,
                        "marker_period_s": 0.0,
                        "fault_check_period_s": 0.0,
                        "diagnostics_period_s": 0.2,
                    },
                    logs[name],
                )
            )
        probe.subscribe(DiagnosticArray, "/diagnostics", 100)
        graph = probe.node
        assert probe.spin_until(  # every node listens to its frames, every image reaches us
            lambda: (
                all(
                    graph.count_subscribers(c["frames_topic"]) >= 1
                    and graph.count_publishers(c["image_topic"]) >= 1
                    for c in out.values()
                )
                or any(n.poll() is not None for n in nodes)
            ),
            EVENT_S,
        ), {k: v.read_text()[-1500:] for k, v in logs.items()}
        for name, chain in out.items():
            chain["board"].open()
            chain["board"].start()
            logs[f"{name}_driver"] = tmp / f"{name}_driver.log"
            nodes.append(
                start_node(
                    "eit_driver",
                    f"/{chain['patch'].name}",
                    {
                        "patch_config": str(chain["path"]),
                        "port": chain["board"].slave_path,
                        "record_path": str(chain["mcap"]),
                        "diagnostics_period_s": 0.2,
                        "publish_tf": False,
                    },
                    logs[f"{name}_driver"],
                )
            )

        assert probe.spin_until(  # every node has its reference: the boards play the recording
            lambda: (
                all(
                    node_status(probe, c["patch"].name, "eit_reconstruction").get("reference_ready")
                    == "true"
                    for c in out.values()
                )
                or any(n.poll() is not None for n in nodes)
            ),
            EVENT_S,
        ), {k: v.read_text()[-1500:] for k, v in logs.items()}
        go.set()

        def imaged(chain) -> int:  # images of recording frames (not the reference) that came
            frames = probe.messages[chain["frames_topic"]]
            first = bytes(frames[0][1].voltages) if frames else b""
            varied = {stamp_ns(m) for _, m in frames if bytes(m.voltages) != first}
            return sum(stamp_ns(m) in varied for _, m in probe.messages[chain["image_topic"]])

        # the boards play until each node has imaged enough of the recording: on a loaded
        # machine a best-effort node skips frames, so count its images, not the frames sent
        assert probe.spin_until(
            lambda: (
                all(imaged(c) >= VARIED + 5 for c in out.values())
                or any(n.poll() is not None for n in nodes)
            ),
            EVENT_S,
        ), {k: v.read_text()[-1500:] for k, v in logs.items()}
        for chain in out.values():
            chain["board"].stop()  # the boards fall silent: what was sent is what is imaged

        for chain in out.values():
            chain["status"] = node_status(probe, chain["patch"].name, "eit_driver")
    finally:  # every node stopped before the tests read the recordings (closed on exit)
        codes = [stop_node(node) for node in nodes]
        for chain in out.values():
            chain["board"].close()
        probe.close()
    assert codes == [0] * len(codes), {k: v.read_text()[-1500:] for k, v in logs.items()}
    return out, probe


def node_status(probe: Probe, patch_name: str, node: str) -> dict[str, str]:
    """The latest diagnostics values of ``/<patch_name>/<node>``, with level and message."""
    for _, msg in reversed(probe.messages["/diagnostics"]):
        for status in msg.status:
            if f"/{patch_name}/{node}" in status.name:
                level = status.level
                level = level[0] if isinstance(level, bytes) else level
                values = {kv.key: kv.value for kv in status.values}
                return values | {"level": str(level), "message": status.message}
    return {}


def recorded(chain, tmp_path) -> tuple[np.ndarray, np.ndarray]:
    """The driver's own recording as the offline frames (npz) and their stamps."""
    npz = tmp_path / "frames.npz"
    assert main(["frames", "export", str(chain["mcap"]), str(npz)]) == 0
    with np.load(npz) as data:
        return data["frames"], data["t"]


# the first case pays the module's graph (three emulated boards, their drivers and
# reconstruction nodes): ~40 s idle (172 s at load 15 on 2 cores)
@pytest.mark.timeout(180)
@pytest.mark.parametrize("name", list(BOARDS))
def test_the_driver_publishes_what_the_board_sent_none_lost(chains, name, tmp_path):
    out, _ = chains
    chain = out[name]
    frames, _ = recorded(chain, tmp_path)
    board = chain["board"]
    expected = np.array(
        [board.expected_measurements(i) for i in range(board.frames_sent)], dtype=np.float32
    )
    # the first frames the driver saw may have been written before it opened the port: align
    # on the first frame of the recording (the reference frames before it are all alike)
    frames32 = frames.astype(np.float32)
    j = next(k for k in range(len(frames32)) if not np.array_equal(frames32[k], frames32[0]))
    first = chain["switch"]["at"] - j
    assert first >= 0 and np.array_equal(frames32[0], expected[first])
    n = len(frames)
    np.testing.assert_array_equal(frames.astype(np.float32), expected[first : first + n])
    assert n - j >= VARIED
    assert chain["status"]["profile"] == BOARDS[name][1]["profile"]
    status = chain["status"]
    # at most the tail of a line the board was writing when the driver opened the port
    assert int(status["frames_rejected"]) == int(status.get("rejected_partial_line", 0)) <= 1, (
        status
    )


@pytest.mark.parametrize("name", list(BOARDS))
def test_images_equal_eit_skin_reconstruct_of_the_drivers_recording(chains, name, tmp_path):
    out, probe = chains
    chain = out[name]
    frames, _ = recorded(chain, tmp_path)
    result = tmp_path / "images.npz"
    args = ["reconstruct", "--patch", str(chain["path"]), "--frames", str(tmp_path / "frames.npz")]
    args += ["--out", str(result), "--cache-dir", str(chain["cache"])]
    args += ["--reference", "capture", "--reference-frames", str(REFERENCE_FRAMES)]
    args += ["--drift-time-constant", "0", "--fault-check-period", "0"]
    assert main(args) == 0
    with np.load(result) as data:
        physical, imaged = data["physical"], data["imaged"]
    online = {
        stamp_ns(m): np.frombuffer(bytes(m.data), np.float32).reshape(m.height, m.width)
        for _, m in probe.messages[chain["image_topic"]]
    }
    stamps = [record.stamp_ns for _, _, record in read_mcap_frames(chain["mcap"])]
    varied = [k for k in range(len(stamps)) if imaged[k] and stamps[k] in online]
    varied = [k for k in varied if not np.array_equal(frames[k], frames[0])]
    assert len(varied) >= 0.9 * VARIED, (len(varied), len(online))
    different = [k for k in varied if not np.array_equal(online[stamps[k]], physical[k], True)]
    assert different == []
    assert np.nanmax(np.abs(physical[varied])) > 0  # the recording's changes show


def test_a_board_in_another_format_gives_an_error_naming_port_profile_and_bytes(repo, tmp_path):
    """A Sciospec-profile layer on a port where an OpenEIT board streams its lines."""
    data = yaml.safe_load((repo / "data/real/hydrogel_ohmc16.yaml").read_text())
    data["layers"][0]["device"] = {"profile": "sciospec", "ack_timeout_s": 0.3}
    path = tmp_path / "wrong_board.yaml"
    path.write_text(yaml.safe_dump(data))
    patch = load_patch(path)
    protocol = build_protocol(patch.layers[0].protocol, 16)
    board = OpenEITEmulator(lambda i: np.full(protocol.n_measurements, 100.0), protocol, 20.0)
    probe = Probe("wrong_board_probe")
    probe.subscribe(DiagnosticArray, "/diagnostics", 100)
    log = tmp_path / "driver.log"
    board.open()
    board.start()
    node = start_node(
        "eit_driver",
        "/wrong",
        {"patch_config": str(path), "port": board.slave_path, "diagnostics_period_s": 0.2},
        log,
    )
    try:
        assert probe.spin_until(
            lambda: (
                node_status(probe, "wrong", "eit_driver").get("level") == "2"
                or node.poll() is not None
            ),
            EVENT_S,
        ), log.read_text()
        status = node_status(probe, "wrong", "eit_driver")
    finally:
        assert stop_node(node) == 0
        board.close()
        probe.close()
    message = status["message"]
    assert board.slave_path in message and "sciospec" in message, message
    assert "saw b'" in message and "100.0000," in message, message  # what the board sends
    assert "no acknowledgement of stop (b4 01 00 b4)" in message, message
    assert status["frames_published"] == "0"
