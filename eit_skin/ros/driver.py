"""``eit_driver``: raw EIT frames of one skin patch from a board, the simulator or a recording.

Publishes ``eit_skin_msgs/EitFrame`` on ``<namespace>/<layer>/frames`` (reliable, bounded
depth: :mod:`eit_skin.ros.qos`), one topic per layer, stamped with the acquisition time, and
``/diagnostics`` (names: :mod:`eit_skin.ros.topics`) with its lifecycle state. A lifecycle
node by default that configures and activates itself (``managed``, ``autostart``:
:class:`DriverNode`); ``ros2 lifecycle set <ns>/eit_driver deactivate`` stops its frames.

Sources, chosen by parameters:

* ``replay_path`` set: an MCAP recording (original timing, or as fast as possible);
* ``port`` set: a skin board on a serial port (wire protocol in docs/wire-protocol.md),
  serving the layer named by ``layer`` (default: the patch's first layer); the port is
  retried with backoff while absent and the node keeps running;
* otherwise the physics simulator runs the ``scenario`` touch script on every layer; a
  script with a joint posture (the elbow) also publishes the simulated joint angle on
  ``/joint_states``, as the robot's joint state publisher would.
"""

from __future__ import annotations

import math
import sys
import traceback

import rclpy
import rclpy.time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from sensor_msgs.msg import JointState

from eit_skin.frames import FrameRecord
from eit_skin.hardware.sources import (
    BOARD_SOURCES,
    LayerFrameFactory,
    ReplaySource,
    SimulatedSource,
    SourceStatus,
    board_source,
)
from eit_skin.io.mcap import McapFrameWriter
from eit_skin.patch.loading import load_patch
from eit_skin.patch.model import PatchError
from eit_skin.resources import config_path
from eit_skin.ros.node_runner import (
    LiveParameters,
    declare_parameters,
    diagnostic_status,
    run_node,
)
from eit_skin.ros.parameters import DRIVER, WRITABLE
from eit_skin.ros.qos import OVERRIDABLE, RAW_FRAMES
from eit_skin.ros.topics import DIAGNOSTICS, patch_topics
from eit_skin.sim.faults import parse_faults


class DriverNode(LifecycleNodeMixin, Node):
    """Thin adapter: parameters -> a frame source -> EitFrame messages; a lifecycle node.

    States (``managed``, the default, as the ouster-ros and realsense-ros drivers):
    *unconfigured* (nothing open); *configure*: load the patch, open the board (its reader
    thread starts, retrying an absent port) or set up the simulator or recording, publish the
    static transform; *activate*: publish frames; *deactivate*: stop publishing (a board's
    frames are read and dropped, its port stays open; the simulator's script pauses);
    *cleanup* / *shutdown*: close the port and the recording. ``autostart`` (default true)
    configures and activates at construction, so the node behaves like a plain one unless a
    lifecycle manager is wanted. ``managed:=false``: no lifecycle services at all, the same
    configure and activate at construction. ``/diagnostics`` report the lifecycle state from
    construction on.
    """

    def __init__(self, **kwargs) -> None:
        Node.__init__(self, "eit_driver", **kwargs)
        self.params = p = declare_parameters(self, DRIVER, "eit_driver")
        self.managed = bool(p["managed"])
        LifecycleNodeMixin.__init__(self, enable_communication_interface=self.managed)
        self.diagnostics = self.create_publisher(
            DiagnosticArray, DIAGNOSTICS, 10, qos_overriding_options=OVERRIDABLE
        )
        self.diagnostics_timer = self.create_timer(
            float(p["diagnostics_period_s"]), self._publish_diagnostics
        )
        self.live = LiveParameters(self, WRITABLE["eit_driver"], self._apply_parameters)
        self.patch = None
        self.source = None
        self.recorder: McapFrameWriter | None = None
        self.factories: dict[str, LayerFrameFactory] = {}
        self.frame_publishers: dict[str, object] = {}
        self.joint_states = None
        self.static_tf = None
        self.acquire_timer = None
        self.active = False
        self.frames_held = 0  # frames read from a board while inactive (not published)
        self.hardware_id = str(p["port"]) or ("replay" if p["replay_path"] else "simulator")
        self.waits_for = 0
        self.configure_error: Exception | None = None
        self._constructed = False
        if not self.managed or p["autostart"]:
            self.trigger_configure()
            if self.configure_error is not None:
                raise self.configure_error  # a bad configuration: refuse to start (see main)
            self.trigger_activate()
        self._constructed = True

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Load the patch, open the board or set up the simulator or replay (not publishing)."""
        self.configure_error = None
        try:
            self._configure()
        except (PatchError, FileNotFoundError, KeyError, ValueError, OSError) as error:
            self._release()
            self.configure_error = error
            if self._constructed:  # a manager's request: say why it failed
                self.get_logger().error(f"configure failed: {error}")
            return TransitionCallbackReturn.FAILURE
        except Exception as error:  # rclpy would swallow it without a word
            self._release()
            self.configure_error = error
            self.get_logger().error(f"configure failed: {traceback.format_exc()}")
            return TransitionCallbackReturn.ERROR
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Publish frames from now on (the simulator's or replay's steps run again)."""
        self.active = True
        if self.acquire_timer is not None:
            self.acquire_timer.reset()
        self.get_logger().info(f"active: publishing {', '.join(self.factories)}")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop publishing; a board's port stays open, the simulator's script pauses."""
        self.active = False
        if self.acquire_timer is not None:
            self.acquire_timer.cancel()
        self.get_logger().info("inactive: not publishing")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Close the port and the recording, forget the patch."""
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Close everything (from any state)."""
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """An error in a transition: close everything and go back to unconfigured."""
        self._release()
        return TransitionCallbackReturn.SUCCESS

    @property
    def lifecycle_state(self) -> str:
        """``unconfigured``, ``inactive``, ``active`` or ``finalized`` (or a transition)."""
        return str(self._state_machine.current_state[1])

    def _configure(self) -> None:
        p = self.params
        path = config_path(str(p["patch_config"]))
        self.patch = load_patch(path)  # PatchError: refuse to configure
        frame_id = str(p["frame_id"]) or self.patch.frame_id
        port, replay = str(p["port"]), str(p["replay_path"])
        if p["layer"]:
            layers = [self.patch.layer(str(p["layer"]))]
        elif port and len(self.patch.layers) > 1:
            # a board serves one layer: guessing one would leave the others silent
            raise ValueError(
                f"port {port!r}: patch {self.patch.name!r} has layers "
                f"{', '.join(self.patch.layer_names)}, one board each; set layer "
                "(one eit_driver per board)"
            )
        else:
            layers = list(self.patch.layers)
        self.factories = {
            layer.name: LayerFrameFactory(self.patch, layer, frame_id) for layer in layers
        }
        topics = patch_topics(self.patch)
        self.frame_publishers = {
            name: self.create_publisher(
                _msg_type(),
                topics.layers[name].frames,
                RAW_FRAMES,
                qos_overriding_options=OVERRIDABLE,
            )
            for name in self.factories
        }
        #: recordings hold absolute topic names (the node's namespace resolved)
        self.record_topics = patch_topics(self.patch, self.get_namespace())
        # thread-safe, and flushed at least every 0.5 s: a killed driver leaves a readable file
        self.recorder = McapFrameWriter(p["record_path"]) if p["record_path"] else None
        self.waits_for = int(p["wait_for_subscribers"])
        self.frames_held = 0

        if replay:
            self.source = ReplaySource(replay, list(self.factories), bool(p["replay_realtime"]))
            self.acquire_timer = self.create_timer(
                0.001, lambda: self._when_subscribed(self.source.tick), autostart=False
            )
        elif port:
            (layer,) = layers
            self.source = board_source(
                self.factories[layer.name], port, int(p["baud"]), self.publish
            )
            self.source.start()
        else:
            self.source = self._simulated_source(p)
            self.joint_name = str(p["sim_joint_name"])
            if self.source.simulator.scenario.posture is not None:
                self.joint_states = self.create_publisher(
                    JointState, topics.joint_states, 10, qos_overriding_options=OVERRIDABLE
                )
            self.acquire_timer = self.create_timer(
                1.0 / float(p["rate_hz"]),
                lambda: self._when_subscribed(self._simulate),
                autostart=False,
            )
        mount = self.patch.mount
        pose = p["tf_pose"] if p["tf_pose"] is not None else [*mount.xyz, *mount.rpy]
        self.static_tf = (
            self._publish_static_transform(
                str(p["tf_parent_frame"]) or mount.parent_frame,
                frame_id,
                [float(v) for v in pose],
            )
            if p["publish_tf"]
            else None
        )
        self.get_logger().info(
            f"patch {self.patch.name!r} ({path}), layers {list(self.factories)}, "
            f"source {self.hardware_id}, frame_id {frame_id!r}"
        )

    def _release(self) -> None:
        """Close the port and the recording, drop the frames' publishers and timers.

        Idempotent; the serial reader thread is joined first.
        """
        self.active = False
        if isinstance(self.source, BOARD_SOURCES):
            self.source.stop()
        self.source = None
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None
        if self.acquire_timer is not None:
            self.destroy_timer(self.acquire_timer)
            self.acquire_timer = None
        for publisher in [*self.frame_publishers.values(), self.joint_states, self.static_tf]:
            if publisher is not None:
                self.destroy_publisher(publisher)
        self.frame_publishers, self.joint_states, self.static_tf = {}, None, None
        self.factories = {}

    def _apply_parameters(self, values: dict[str, object]) -> None:
        """Writable parameters set while running (the diagnostics period)."""
        if "diagnostics_period_s" in values:
            self.diagnostics_timer.timer_period_ns = round(
                float(values["diagnostics_period_s"]) * 1e9
            )

    def _publish_static_transform(self, parent: str, child: str, pose: list[float]):
        """``parent -> child`` on /tf_static, latched like tf2_ros's static broadcaster.

        Returns the publisher, or None when tf2_msgs is missing (said once in the log; the
        skin runs on without TF).
        """
        if len(pose) != 6:
            raise ValueError(f"tf_pose: expected x y z roll pitch yaw, got {pose}")
        try:
            from tf2_msgs.msg import TFMessage
        except ImportError:
            self.get_logger().warning(
                f"tf2_msgs is not installed: no static transform {parent} -> {child} "
                "on /tf_static (apt install ros-$ROS_DISTRO-tf2-msgs)"
            )
            return None
        from geometry_msgs.msg import TransformStamped

        latched = QoSProfile(
            depth=1,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
            reliability=ReliabilityPolicy.RELIABLE,
        )
        publisher = self.create_publisher(
            TFMessage, "/tf_static", latched, qos_overriding_options=OVERRIDABLE
        )
        transform = TransformStamped()
        transform.header.stamp = self.get_clock().now().to_msg()
        transform.header.frame_id, transform.child_frame_id = parent, child
        t = transform.transform
        t.translation.x, t.translation.y, t.translation.z = pose[:3]
        t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w = quaternion_from_rpy(*pose[3:])
        publisher.publish(TFMessage(transforms=[transform]))
        return publisher

    def _simulated_source(self, p: dict) -> SimulatedSource:
        from eit_skin.sim.simulator import SkinSimulator

        simulator = SkinSimulator(
            self.patch,
            str(p["scenario"]) or "demo",
            rate_hz=float(p["rate_hz"]),
            seed=int(p["seed"]),
            faults=parse_faults(str(p["faults"])),
        )
        return SimulatedSource(self.factories, simulator, simulator.n_frames, bool(p["loop"]))

    def _when_subscribed(self, step) -> None:
        """Run a simulator/replay step, holding the script until someone listens.

        Without this the first frames of a script would be lost to DDS discovery (and a
        reconstruction node would take its no-load reference in the middle of a touch).
        """
        if self.waits_for and all(
            pub.get_subscription_count() < self.waits_for for pub in self.frame_publishers.values()
        ):
            return
        self.waits_for = 0
        step(self._now_ns(), self.publish)

    def _simulate(self, now: int, sink) -> None:
        self.source.tick(now, sink)
        angle = self.source.posture_angle()
        if self.joint_states is not None and angle is not None:
            msg = JointState(name=[self.joint_name], position=[angle])
            msg.header.stamp = rclpy.time.Time(nanoseconds=now).to_msg()
            self.joint_states.publish(msg)

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def publish(self, record: FrameRecord) -> None:
        """Publish one frame while active (callable from the serial reader thread)."""
        if not self.active:
            self.frames_held += 1  # a board read while inactive: its port stays open
            return
        self.frame_publishers[record.layer].publish(record.to_msg())
        if self.recorder is not None:
            self.recorder.write(
                self.record_topics.layers[record.layer].frames, record, self._now_ns()
            )

    def _publish_diagnostics(self) -> None:
        state = self.lifecycle_state
        values = {"lifecycle_state": state, "managed": str(self.managed).lower()}
        if self.source is None:
            status = SourceStatus(0, f"{state}: no source open (lifecycle)", values)
        else:
            status = self.source.status()
            status = SourceStatus(status.level, status.message, {**values, **status.values})
            if not self.active:
                # a paused simulator or replay is no fault; a board's port state still counts
                board = isinstance(self.source, BOARD_SOURCES)
                status = SourceStatus(
                    status.level if board else 0,
                    f"{state}: not publishing (lifecycle)"
                    + (f"; board: {status.message}" if board else ""),
                    {**status.values, "frames_held_inactive": str(self.frames_held)},
                )
            elif self.waits_for and not isinstance(self.source, BOARD_SOURCES):
                # holding the script until a subscriber listens is normal, not a fault
                topics = ", ".join(
                    self.resolve_topic_name(p.topic) for p in self.frame_publishers.values()
                )
                status = SourceStatus(
                    0,
                    f"waiting for {self.waits_for} subscriber(s) on {topics}",
                    {**status.values, "waiting_for_subscribers": str(self.waits_for)},
                )
        # one call site per severity: rclpy refuses a severity change at one call site
        if status.level > 1:
            self.get_logger().error(status.message, throttle_duration_sec=10.0)
        elif status.level == 1:
            self.get_logger().warning(status.message, throttle_duration_sec=10.0)
        layers = ", ".join(self.factories) or str(self.params["layer"])
        name = self.get_fully_qualified_name() + (f": {layers}" if layers else "")
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [
            diagnostic_status(
                status.level,
                name,
                status.message,
                self.hardware_id,
                status.values,
            )
        ]
        self.diagnostics.publish(msg)

    def close_resources(self) -> None:
        """Stop the serial reader thread and close the recording (idempotent)."""
        self._release()

    def destroy_node(self) -> None:
        self.close_resources()
        super().destroy_node()


def quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, ...]:
    """(x, y, z, w) of fixed-axis roll, then pitch, then yaw (as tf2 and URDF rpy)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


def _msg_type():
    from eit_skin_msgs.msg import EitFrame

    return EitFrame


def main(args: list[str] | None = None) -> int:
    """Console script ``eit_driver``; exit 2 on a bad configuration."""
    return run_node(DriverNode, "eit_driver", args)


if __name__ == "__main__":
    sys.exit(main())
