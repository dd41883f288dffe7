"""Every parameter of the three nodes: name, default (which fixes the type) and meaning.

One home for them, free of rclpy: the nodes declare them with these descriptors
(:func:`eit_skin.ros.node_runner.declare_parameters`), the launch files offer each one as a
launch argument (:func:`launch_overrides`), and ``python -m eit_skin.ros.param_docs`` writes
the parameter tables of docs/nodes.md from them (a test fails when the page is stale). The
classifier's settings are declared once, in :class:`~eit_skin.touch.config.ClassifierConfig`,
and listed here from there.
"""

from __future__ import annotations

from eit_skin.pipeline.processor import (
    DEFAULT_CONTACT_K,
    DEFAULT_DRIFT_TIME_CONSTANT_S,
    DEFAULT_FAULT_CHECK_PERIOD_S,
    DEFAULT_JUMP_K,
    FAULT_WINDOW_FRAMES,
)
from eit_skin.sim.faults import fault_help
from eit_skin.touch.classifier import LIVE_SETTINGS
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.settings import Setting, declared_settings

#: (name, default, description) of a node parameter; the default fixes its type.
ParameterTable = list[tuple[str, object, str]]

UNSET_DOUBLES: tuple[float, ...] = ()
"""Default of a double-array parameter that is unset unless given (then the patch decides)."""

PATCH_CONFIG = (
    "patch_config",
    "arm",
    "patch YAML path, or a shipped patch name (arm, face, elbow)",
)

DRIVER: ParameterTable = [
    PATCH_CONFIG,
    (
        "managed",
        True,
        "a lifecycle node (configure: load the patch, open the board or set up the simulator; "
        "activate: publish; deactivate: stop publishing, keep the port; cleanup, shutdown: "
        "close it); false: a plain node that acquires and publishes from start to stop",
    ),
    (
        "autostart",
        True,
        "managed only: configure and activate at start (as without a lifecycle manager); "
        "false: wait unconfigured for the manager's transitions",
    ),
    (
        "layer",
        "",
        "layer to serve; empty: every layer (simulator, replay); a serial board serves one "
        "layer, so a patch of several layers needs it with port (refused otherwise)",
    ),
    ("port", "", "serial device of the skin board, e.g. /dev/eit_skin_arm; empty: simulator"),
    (
        "baud",
        0,
        "serial rate, bit/s; 0: the board profile's (the layer's device.baud); ignored by USB "
        "CDC-ACM boards",
    ),
    ("rate_hz", 50.0, "simulator frame rate, Hz"),
    ("frame_id", "", "override of the patch config's frame_id"),
    (
        "record_path",
        "",
        "record every published frame to this MCAP file (rosbag2 layout, flushed every 0.5 s: "
        "a killed driver loses at most its last 0.5 s)",
    ),
    ("replay_path", "", "replay the EitFrames of this MCAP file instead of acquiring"),
    ("replay_realtime", True, "replay with the recording's timing (false: as fast as possible)"),
    (
        "wait_for_subscribers",
        1,
        "simulator/replay: hold the first frame until a frame topic has this many subscribers "
        "(0: start at once); serial boards never wait",
    ),
    ("scenario", "", "simulator touch script: built-in name or YAML path; empty: demo"),
    ("loop", True, "simulator repeats its script (false: one pass, then no touch)"),
    ("seed", 0, "simulator random seed"),
    ("sim_joint_name", "elbow", "simulator: joint name of its posture on /joint_states"),
    ("faults", "", f"simulator faults, comma separated {fault_help(',')}"),
    ("diagnostics_period_s", 1.0, "period of /diagnostics messages, s"),
    (
        "publish_tf",
        True,
        "publish the patch frame's static transform on /tf_static (transient local, like "
        "tf2_ros's static broadcaster); false when the robot's URDF provides it",
    ),
    (
        "tf_parent_frame",
        "",
        "parent of the patch frame in its static transform; empty: the patch's "
        "mount.parent_frame (base_link without a mount block)",
    ),
    (
        "tf_pose",
        UNSET_DOUBLES,
        "patch frame in its parent: x y z (m) roll pitch yaw (rad); unset: the patch's "
        "mount.xyz and mount.rpy (zeros without a mount block)",
    ),
]

RECONSTRUCTION: ParameterTable = [
    PATCH_CONFIG,
    (
        "cache_dir",
        "",
        "reconstruction matrix cache; empty: $EIT_SKIN_CACHE or ~/.cache/eit_skin (never ~/.ros)",
    ),
    ("reference_frames", 0, "frames averaged into the reference; 0: the layer's solver setting"),
    (
        "drift_time_constant_s",
        DEFAULT_DRIFT_TIME_CONSTANT_S,
        "drift tracking time constant while untouched, s; 0: off",
    ),
    (
        "contact_k",
        DEFAULT_CONTACT_K,
        "a change above contact_k x noise counts as contact (freezes drift)",
    ),
    ("joint_name", "", "joint whose angle selects the reference (posture compensation)"),
    ("posture_references", "", "npz from `eit-skin record-postures`; empty: no posture"),
    (
        "posture_wait_s",
        0.5,
        "longest a frame waits for the joint state of its acquisition time, s (posture only)",
    ),
    (
        "pressure_range_pa",
        10000.0,
        "top of the pressure colour scale, Pa (the simulated demo peaks at 7-8 kPa)",
    ),
    (
        "stretch_range",
        0.05,
        "top of the stretch colour scale, strain (the demo's rub and pinch reach 0.03-0.05)",
    ),
    ("marker_period_s", 0.5, "period of the layers' skin_marker updates, s; 0: no marker"),
    (
        "fault_check_period_s",
        DEFAULT_FAULT_CHECK_PERIOD_S,
        f"frame time between checks of the last {FAULT_WINDOW_FRAMES} frames for faulty "
        "electrodes, s; 0: never",
    ),
    (
        "jump_k",
        DEFAULT_JUMP_K,
        "a value that changed by more than jump_k x its channel's noise in one frame is left "
        "out (FLAG_JUMP); 0: no such check",
    ),
    ("frame_timeout_s", 5.0, "no frame on a layer for this long: diagnostics ERROR, s; 0: off"),
    ("diagnostics_period_s", 1.0, "period of /diagnostics messages, s"),
    (
        "calibration",
        "",
        "press calibration npz from `eit-skin calibrate` (its layer gets calibrated_contacts); "
        "empty: off. Refused at start unless the patch has the model's layer, unchanged "
        "(content hash) and with the model's channel count",
    ),
    (
        "calibration_max_touches",
        1,
        "calibrated contacts per frame at most (several touches at once); > 1 needs a "
        "calibration made with `eit-skin calibrate --max-touches`",
    ),
]

CLASSIFIER: ParameterTable = [
    PATCH_CONFIG,
    # every classifier setting the node can honour, as declared (touch/config.py)
    *(
        (s.name, s.default, s.parameter_text())
        for s in declared_settings(ClassifierConfig)
        if s.node
    ),
    ("noise_pa", 0.0, "pressure image noise, Pa; 0: estimated during calibration"),
    (
        "cache_dir",
        "",
        "reconstruction cache (spread map, matrix); empty: $EIT_SKIN_CACHE or ~/.cache/eit_skin",
    ),
    ("pair_timeout_s", 0.1, "wait for the stretch image that pairs with a pressure image, s"),
    (
        "pair_slop_s",
        0.01,
        "largest stamp difference of a paired pressure and stretch image, s (layers on two "
        "boards have their own acquisition clocks; like message_filters' ApproximateTime slop)",
    ),
    (
        "image_timeout_s",
        5.0,
        "no image on a subscribed topic for this long: diagnostics ERROR, s; 0: off",
    ),
    ("diagnostics_period_s", 1.0, "period of /diagnostics messages, s"),
]


def _non_negative(table: ParameterTable, name: str, *, zero: bool) -> Setting:
    """Parameter ``name`` of ``table`` as a :class:`Setting` bounded ``>= 0`` (``> 0``).

    ``zero``: whether 0 is allowed. The bounds check a value set while the node runs.
    """
    _, default, description = next(row for row in table if row[0] == name)
    return Setting(name, default, description, low=0.0, low_open=not zero)


WRITABLE: dict[str, dict[str, Setting]] = {
    "eit_driver": {
        "diagnostics_period_s": _non_negative(DRIVER, "diagnostics_period_s", zero=False)
    },
    "eit_reconstruction": {
        s.name: s
        for s in (
            _non_negative(RECONSTRUCTION, "pressure_range_pa", zero=False),
            _non_negative(RECONSTRUCTION, "stretch_range", zero=False),
            _non_negative(RECONSTRUCTION, "drift_time_constant_s", zero=True),
            _non_negative(RECONSTRUCTION, "contact_k", zero=False),
            _non_negative(RECONSTRUCTION, "frame_timeout_s", zero=True),
            _non_negative(RECONSTRUCTION, "diagnostics_period_s", zero=False),
        )
    },
    "eit_classifier": {
        **{s.name: s for s in declared_settings(ClassifierConfig) if s.name in LIVE_SETTINGS},
        "image_timeout_s": _non_negative(CLASSIFIER, "image_timeout_s", zero=True),
        "diagnostics_period_s": _non_negative(CLASSIFIER, "diagnostics_period_s", zero=False),
    },
}
"""Executable -> its parameters that may change while it runs (``ros2 param set``), with the
bounds a new value is checked against; they take effect on the next frame. Every other
parameter is read-only: read once at start (the patch, the matrices, what calibration learnt
and the buffers depend on it). Why each is safe: docs/nodes.md, "Live tuning"."""

NODE_PARAMETERS: dict[str, ParameterTable] = {
    "eit_driver": DRIVER,
    "eit_reconstruction": RECONSTRUCTION,
    "eit_classifier": CLASSIFIER,
}
"""Executable -> its parameter table."""

GRAPH_PARAMETERS = ("patch_config", "layer", "port")
"""Parameters the node graph sets from the patch and its ports (launch arguments patch, port,
ports, ports_file), not offered as launch arguments of their own."""


def launch_arguments() -> dict[str, str]:
    """Parameter name -> description, for one launch argument per node parameter.

    A parameter of several nodes (``diagnostics_period_s``, ``cache_dir``) is one argument
    that sets it on each of them.
    """
    arguments: dict[str, str] = {}
    for executable, table in NODE_PARAMETERS.items():
        for name, default, description in table:
            if name not in GRAPH_PARAMETERS and name not in arguments:
                arguments[name] = f"{description} [{executable}; default {format_default(default)}]"
    return arguments


def launch_overrides(executable: str, texts: dict[str, str]) -> dict[str, object]:
    """The parameters of ``executable`` given as launch arguments, converted to their types.

    Args:
        executable: ``eit_driver``, ``eit_reconstruction`` or ``eit_classifier``.
        texts: launch argument name -> its text; empty texts are not given.

    Raises:
        ValueError: a text that is not of the parameter's type, naming the argument.
    """
    values: dict[str, object] = {}
    for name, default, _ in NODE_PARAMETERS[executable]:
        text = texts.get(name, "").strip()
        if name in GRAPH_PARAMETERS or not text:
            continue
        values[name] = parse_value(name, default, text)
    return values


def parse_value(name: str, default: object, text: str) -> object:
    """``text`` as a value of ``default``'s type (bool, int, float, str, list of floats)."""
    try:
        if isinstance(default, bool):
            lowered = text.lower()
            if lowered not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                raise ValueError("expected true or false")
            return lowered in ("true", "1", "yes", "on")
        if isinstance(default, int):
            return int(text)
        if isinstance(default, float):
            return float(text)
        if isinstance(default, (list, tuple)):
            items = text.strip("[]").replace(",", " ").split()
            return [float(item) for item in items]
    except ValueError as error:
        raise ValueError(f"launch argument {name}:={text!r}: {error}") from None
    return text


def format_default(default: object) -> str:
    """A default as the docs show it."""
    if isinstance(default, bool):
        return str(default).lower()
    if isinstance(default, str):
        return f'"{default}"' if default else '""'
    if isinstance(default, (list, tuple)):
        return f"[{' '.join(f'{v:g}' for v in default)}]" if default else "unset"
    return f"{default:g}" if isinstance(default, float) else str(default)
