"""Issue 38, point 7: touches in 3-D. The arm (cylinder), the face (height map) and the elbow
(cylinder), each mounted on base_link at a pose of its own: real drivers publish the mounts on
/tf_static, real classifier nodes turn a synthetic press into touch events; each event's
``position`` and ``normal``, carried through those transforms into base_link, must lie on
the placed surface (within 1 mm) and be its outward normal, checked by the surfaces' own
geometry (distance to the cylinder's axis, height above the face's grid)."""

from __future__ import annotations

import numpy as np
import pytest
from eit_skin_msgs.msg import ContactArray, TouchEvent
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import Image

from eit_skin.patch.loading import load_patch
from eit_skin.patch.placement import rotation_from_rpy
from eit_skin.ros.probe import Probe, start_node, stop_node
from eit_skin.ros.topics import patch_topics
from eit_skin.touch.shapes import layer_image_grid
from test.ros.test_classifier_node import image_msg, preroll, wait_for_contacts
from test.support.patch_copies import shipped_patch_data, write_patch
from test.support.patience import EVENT_S

tf2_msgs = pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs not installed")
pytestmark = pytest.mark.ros

#: patch -> (mount xyz m, mount rpy rad, where the press is on the sheet m)
SCENES = {
    "arm": ([0.30, -0.20, 0.90], [0.3, -0.2, 1.2], (0.025, -0.012)),
    "face": ([0.05, 0.00, 1.45], [1.5707963, 0.0, -1.5707963], (0.030, 0.045)),
    "elbow": ([0.25, 0.25, 1.05], [-0.4, 0.5, 0.0], (0.040, -0.030)),
}
LATCHED = QoSProfile(
    depth=5, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE
)


def quaternion_matrix(q) -> np.ndarray:
    """``[3, 3]`` rotation of a geometry_msgs/Quaternion."""
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def on_surface(placement, point: np.ndarray, normal: np.ndarray) -> tuple[float, float]:
    """``(distance m, angle rad)`` of a point and normal (patch frame) from the placed
    surface and its outward normal there, from the surface's own definition."""
    if placement.kind == "cylinder":
        along = np.dot(point - placement.origin, placement.axis)
        radial = point - placement.origin - along * placement.axis
        distance = abs(np.linalg.norm(radial) - placement.radius)
        outward = radial / np.linalg.norm(radial)
    else:  # heightmap: back through its rigid transform, then above the grid
        rotation = rotation_from_rpy(placement.rpy)
        local = (point - placement.origin) @ rotation
        distance = abs(local[2] - placement.height(local[:2])[0])
        e = 1e-5
        slope = [
            (placement.height(local[:2] + d) - placement.height(local[:2] - d))[0] / (2 * e)
            for d in (np.array([e, 0.0]), np.array([0.0, e]))
        ]
        outward = rotation @ np.array([-slope[0], -slope[1], 1.0])
        outward /= np.linalg.norm(outward)
    return distance, float(np.arccos(np.clip(np.dot(normal, outward), -1.0, 1.0)))


def test_touches_lie_on_the_placed_surfaces_in_base_link(tmp_path) -> None:
    probe = Probe("contacts_3d_probe")
    probe.subscribe(tf2_msgs.TFMessage, "/tf_static", LATCHED)
    reliable = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
    nodes, cases = [], {}
    try:
        for name, (xyz, rpy, centre) in SCENES.items():
            data = shipped_patch_data(name)
            data["mount"] = {"parent_frame": "base_link", "xyz": xyz, "rpy": rpy}
            path = str(write_patch(tmp_path, data, f"mounted_{name}"))
            patch = load_patch(path)
            namespace = f"/{name}_3d"
            topics = patch_topics(patch, namespace)
            layer = patch.layers[0]
            probe.subscribe(TouchEvent, topics.touch_events, reliable)
            probe.subscribe(ContactArray, topics.contacts, 50)
            publishers = [
                probe.node.create_publisher(
                    Image, topics.layers[ly.name].image, qos_profile_sensor_data
                )
                for ly in patch.layers  # the arm's stretch too: the classifier pairs them
            ]
            cases[name] = (patch, topics, layer, publishers, centre)
            for node in ("eit_driver", "eit_classifier"):
                log = tmp_path / f"{name}_{node}.log"
                params = {"patch_config": path}
                if node == "eit_classifier":
                    params["diagnostics_period_s"] = 0.02
                nodes.append((start_node(node, namespace, params, log), log))
        assert probe.spin_until(
            lambda: all(p.get_subscription_count() for c in cases.values() for p in c[3]),
            EVENT_S,
        ), "\n".join(log.read_text() for _, log in nodes)
        for name, (patch, topics, _, publishers, centre) in cases.items():
            grids = [layer_image_grid(ly) for ly in patch.layers]
            xx, yy = np.meshgrid(grids[0].x, grids[0].y)
            blob = 6000.0 * np.exp(-((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2) / 2e-5)
            rng = np.random.default_rng(0)

            def send(k: int, touch: bool, grids=grids, blob=blob, rng=rng, pubs=publishers):
                sent = []
                for grid, publisher in reversed(list(zip(grids, pubs, strict=True))):
                    noise = rng.standard_normal(grid.shape)
                    values = 10.0 * noise + touch * blob if grid is grids[0] else 1e-4 * noise
                    sent.append((publisher, image_msg(grid, k, values)))
                for publisher, msg in sent:  # the pressure image last
                    publisher.publish(msg)
                return sent

            contacts = probe.messages[topics.contacts]
            # the classifier's diagnostics are not heard here: preroll paces by its contacts
            probe.messages.setdefault("/diagnostics", [])
            first = preroll(probe, send, contacts, tmp_path / f"{name}_eit_classifier.log")
            for j in range(70):  # 0.4 s quiet, 0.6 s touch, 0.4 s quiet at 50 Hz
                wait_for_contacts(probe, contacts, send(first + j, 20 <= j < 50))
            events = probe.messages[topics.touch_events]
            assert probe.spin_until(
                lambda events=events: any(m.state == TouchEvent.END for _, m in events), EVENT_S
            ), name
        assert probe.spin_until(
            lambda: len({t.child_frame_id for _, m in probe.messages["/tf_static"]
                         for t in m.transforms}) >= 3,
            EVENT_S,
        )  # fmt: skip
    finally:
        for process, log in nodes:
            assert stop_node(process) == 0, log.read_text()
        probe.close()
    transforms = {
        t.child_frame_id: t for _, m in probe.messages["/tf_static"] for t in m.transforms
    }
    for name, (patch, topics, _, _, centre) in cases.items():
        tf = transforms[patch.frame_id]
        assert tf.header.frame_id == "base_link"
        rotation = quaternion_matrix(tf.transform.rotation)
        t = tf.transform.translation
        translation = np.array([t.x, t.y, t.z])
        # the surface in base_link: the placement under the same transform
        events = [m for _, m in probe.messages[topics.touch_events]]
        touches = [m for _, m in probe.messages[topics.contacts] for m in m.contacts]
        assert events and touches
        for msg in [*events, *touches]:
            position = rotation @ [msg.position.x, msg.position.y, msg.position.z] + translation
            normal = rotation @ [msg.normal.x, msg.normal.y, msg.normal.z]
            # back into the patch frame with the transform's inverse, as a controller's
            # lookup would go the other way
            local = rotation.T @ (position - translation)
            distance, angle = on_surface(patch.placement, local, rotation.T @ normal)
            assert distance < 1e-3 and angle < 1e-3, (name, distance, angle)
            assert np.linalg.norm(normal) == pytest.approx(1.0, abs=1e-6)
            # and it is the touch's own sheet point carried there
            sheet = np.array([msg.centroid.x, msg.centroid.y])
            expected = rotation @ patch.placement.to_3d(sheet)[0] + translation
            assert np.linalg.norm(position - expected) < 1e-6
        mid = events[len(events) // 2]
        assert (mid.centroid.x, mid.centroid.y) == pytest.approx(centre, abs=0.006)
        # not the flat sheet's point: the surface lifts it off z = 0 by centimetres
        flat = rotation @ [mid.centroid.x, mid.centroid.y, 0.0] + translation
        assert (
            np.linalg.norm(
                flat - (rotation @ [mid.position.x, mid.position.y, mid.position.z] + translation)
            )
            > 0.01
        )
