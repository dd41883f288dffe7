"""Skin patch descriptions: the validated, SI-unit dataclasses and their content hash.

A patch is one piece of skin on the robot: a ROS ``frame_id``, a 3-D
:mod:`placement <eit_skin.patch.placement>` for visualisation and one or more
stacked **layers**, each its own EIT domain (outline, holes, electrodes,
material, protocol, mesh and solver settings). Files are read by
:mod:`eit_skin.patch.loading`; the schema is documented in ``docs/patch-schema.md``.

Conventions (metres, patch frame):

* outlines are counter-clockwise; arc-length positions are measured
  counter-clockwise from the outline's first vertex (circle: the point at
  angle 0, ``center + (radius, 0)``; rectangle: the lower-left corner;
  polygon: the first listed point);
* holes are stored clockwise (the sheet is left of every boundary loop);
* electrodes are numbered counter-clockwise in the order of their centres.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, fields, is_dataclass, replace
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

from eit_skin.patch import geometry
from eit_skin.patch.device import DEFAULT_DEVICE, DeviceSpec
from eit_skin.patch.material import Material
from eit_skin.patch.placement import Placement
from eit_skin.patch.protocol import Protocol, ProtocolSpec, build_protocol
from eit_skin.patch.yaml_reader import ConfigError

__all__ = [
    "METHODS",
    "METHODS_WITH_PRIOR",
    "PRIOR_KINDS",
    "AccuracyTarget",
    "Electrode",
    "Layer",
    "MeshSpec",
    "Patch",
    "PatchError",
    "SolverSpec",
]


class PatchError(ConfigError):
    """A patch file is invalid: ``"<file>: <key path>: <reason>"``."""


# --------------------------------------------------------------------------- data types


@dataclass(frozen=True, eq=False)
class Electrode:
    """One boundary electrode.

    Attributes:
        start_m, end_m: arc-length positions (m) of its ends along the outline, measured
            counter-clockwise from the outline's start point, in ``[0, perimeter)``;
            ``end_m < start_m`` when the electrode covers the start point.
        width_m: length along the outline, m.
        center: ``[2]`` point of the outline at its middle, m.
        center_m: arc-length position of its middle, m.
    """

    start_m: float
    end_m: float
    width_m: float
    center: np.ndarray
    center_m: float


@dataclass(frozen=True)
class MeshSpec:
    """Mesh sizing of one layer.

    Attributes:
        max_edge_m: global target edge length, m.
        electrode_edge_m: edge length on and next to electrodes, m (<= max_edge_m).
        min_angle_deg: smallest triangle angle Triangle must guarantee, degrees (0, 34].
        inverse_max_edge_m: edge length of the coarse inverse mesh, m, or ``None`` (same mesh).
    """

    max_edge_m: float
    electrode_edge_m: float
    min_angle_deg: float = 30.0
    inverse_max_edge_m: float | None = None

    def __post_init__(self) -> None:
        if not self.max_edge_m > 0:
            raise ValueError(f"max_edge: must be > 0 m, got {self.max_edge_m}")
        if not 0 < self.electrode_edge_m <= self.max_edge_m:
            raise ValueError(
                f"electrode_edge: must be > 0 and <= max_edge ({self.max_edge_m} m), "
                f"got {self.electrode_edge_m}"
            )
        if not 0 < self.min_angle_deg <= 34:
            raise ValueError(
                f"min_angle: must be in (0, 34] degrees (Triangle's guaranteed range), "
                f"got {self.min_angle_deg}"
            )
        if self.inverse_max_edge_m is not None and not self.inverse_max_edge_m > 0:
            raise ValueError(f"inverse_max_edge: must be > 0 m, got {self.inverse_max_edge_m}")


@dataclass(frozen=True)
class AccuracyTarget:
    """What a layer's model must achieve, instead of mesh sizes (``solver.accuracy_target``).

    The pipeline picks the coarsest forward and inverse meshes, pixel count and Gauss-Newton
    iteration count that meet it on the package's simulated phantom set
    (:mod:`eit_skin.pipeline.model_choice`, docs/reconstruction.md).

    Attributes:
        position_error_percent: largest position error of a small target, percent of the
            sheet's equivalent radius ``R = sqrt(area / pi)`` (> 0).
        amplitude_error_percent: largest error of a target's imaged amplitude (the image's
            integral over the true change's integral, GREIT's amplitude response) from 1,
            percent, or ``None`` (not asked for).
        source: file the target was read from (error messages only; not hashed).
        key: its key path in that file (error messages only; not hashed).
    """

    position_error_percent: float
    amplitude_error_percent: float | None = None
    source: str = field(default="<dict>", compare=False)
    key: str = field(default="solver.accuracy_target", compare=False)

    #: Where the target was written: named in errors, never part of the model's content hash.
    HASH_EXCLUDE: ClassVar[tuple[str, ...]] = ("source", "key")

    def __post_init__(self) -> None:
        if not self.position_error_percent > 0:
            raise ValueError(
                f"position_error_percent: must be > 0, got {self.position_error_percent}"
            )
        if self.amplitude_error_percent is not None and not self.amplitude_error_percent > 0:
            raise ValueError(
                f"amplitude_error_percent: must be > 0, got {self.amplitude_error_percent}"
            )


METHODS: tuple[str, ...] = ("one_step", "greit", "gauss_newton")
"""Names ``solver.method`` may take; :mod:`eit_skin.inverse` implements each of them
(:func:`eit_skin.inverse.dispatch.make_reconstructor`)."""

METHODS_WITH_PRIOR: tuple[str, ...] = ("one_step", "gauss_newton")
"""Methods that use ``solver.prior``."""

PRIOR_KINDS: tuple[str, ...] = ("tikhonov", "laplace", "noser")
"""Names ``solver.prior`` may take; :func:`eit_skin.inverse.priors.make_prior` builds each."""

CHANNEL_WEIGHTS: tuple[str, ...] = ("measured", "equal")
"""Names ``solver.channel_weights`` may take (``LayerImager.use_reference`` honours it)."""

DEFAULT_CHANNEL_WEIGHTS = "equal"
"""``solver.channel_weights`` when not given: chosen with the prior, noise figure and model-error
share by leaving one set out over the real recordings (tanks at their fitted depths) and the
simulator (``bench/standing/real_data.md``); EIDORS's and pyEIT's default too."""

DEFAULT_PRIOR = "noser"
"""``solver.prior`` when not given: chosen with the one-step default noise figure and the
model-error share by leaving one set out over the real recordings and the simulator
(``bench/standing/real_data.md``)."""


@dataclass(frozen=True)
class SolverSpec:
    """Reconstruction settings of one layer (used by the reconstruction engine).

    Attributes:
        method: ``"one_step"`` (linearised, precomputed matrix with ``prior``), ``"greit"``
            (the trained one-step matrix, no prior) or ``"gauss_newton"`` (iterative, with
            ``prior``); :data:`METHODS`.
        prior: regularisation ``"noser"``, ``"laplace"`` or ``"tikhonov"`` (default
            :data:`DEFAULT_PRIOR`).
        hyperparameter: regularisation weight, or ``None`` to choose it from ``noise_figure``.
        noise_figure: target noise figure for the automatic hyperparameter (> 0), or ``None``
            for the method's default (:data:`eit_skin.inverse.methods.DEFAULT_NOISE_FIGURE`).
        max_iterations: Gauss-Newton iterations (>= 1).
        image_pixels: pixels along the long side of the ``H x W`` image grid (>= 8).
        reference_frames: frames averaged into the reference (no-touch) measurement (>= 1).
        channel_weights: ``"measured"`` (each channel weighted by its measured noise, relative
            to the median channel's) or ``"equal"`` (every channel alike, as EIDORS and pyEIT);
            one-step and GREIT only (:data:`CHANNEL_WEIGHTS`, default
            :data:`DEFAULT_CHANNEL_WEIGHTS`).
        accuracy_target: what the model must achieve (:class:`AccuracyTarget`), or ``None``;
            with a target the mesh sizes, ``image_pixels`` and ``max_iterations`` are chosen
            by the pipeline and may not be given.
    """

    method: str = "one_step"
    prior: str = DEFAULT_PRIOR
    hyperparameter: float | None = None
    noise_figure: float | None = None
    max_iterations: int = 5
    image_pixels: int = 64
    reference_frames: int = 20
    accuracy_target: AccuracyTarget | None = None
    channel_weights: str = DEFAULT_CHANNEL_WEIGHTS

    #: Keys added after patches were hashed: left out of the content hash at their default.
    HASH_ONLY_IF_SET: ClassVar[tuple[str, ...]] = ("accuracy_target", "channel_weights")

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method: unknown {self.method!r}; expected one of {METHODS}")
        if self.prior == "greit":
            raise ValueError("prior: 'greit' is a method, not a prior; write method: greit")
        if self.prior not in PRIOR_KINDS:
            raise ValueError(f"prior: unknown {self.prior!r}; expected one of {PRIOR_KINDS}")
        if self.hyperparameter is not None and not self.hyperparameter > 0:
            raise ValueError(f"hyperparameter: must be > 0 or null, got {self.hyperparameter}")
        if self.noise_figure is not None and not self.noise_figure > 0:
            raise ValueError(f"noise_figure: must be > 0, got {self.noise_figure}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations: must be >= 1, got {self.max_iterations}")
        if self.image_pixels < 8:
            raise ValueError(f"image_pixels: must be >= 8, got {self.image_pixels}")
        if self.reference_frames < 1:
            raise ValueError(f"reference_frames: must be >= 1, got {self.reference_frames}")
        if self.channel_weights not in CHANNEL_WEIGHTS:
            raise ValueError(
                f"channel_weights: unknown {self.channel_weights!r}; expected one of "
                f"{CHANNEL_WEIGHTS}"
            )


def tank_refusal(material: Material, electrodes: tuple[Electrode, ...]) -> str | None:
    """Why a layer cannot be a tank (``layers[].depth``), or None.

    A tank is a pressure layer whose electrodes, as high as they are wide, share one width.
    """
    if material.quantity != "pressure":
        return f"a {material.quantity} layer is a thin sheet: no depth"
    widths = np.array([e.width_m for e in electrodes])
    if np.ptp(widths) > 1e-9 * widths.max():
        return "needs electrodes of one width (their height on the wall)"
    return None


@dataclass(frozen=True, eq=False)
class Layer:
    """One sheet of a patch: its own EIT domain.

    Attributes:
        name: layer name, unique in the patch.
        outline_kind: ``"circle"``, ``"rectangle"`` or ``"polygon"`` (as written in the file).
        outline: ``[n, 2]`` CCW polygon, m (circles discretised into regular polygons).
        holes: ``[k_i, 2]`` clockwise polygons, m, strictly inside the outline.
        electrodes: electrodes in counter-clockwise order.
        contact_impedance_ohm_m: 2-D complete-electrode-model contact impedance, ohm*m: one
            for all electrodes, or a tuple of one per electrode (e.g. from
            ``eit-skin fit-device``).
        current_a: injected current amplitude, A.
        protocol: drive/measurement protocol.
        material: sheet material.
        mesh: mesh sizing.
        solver: reconstruction settings.
        device: the board the layer is read from (profile and options); not part of the
            content hash (it changes no model) except ``negative_input_gain`` when not 1
            (:attr:`measured_protocol`).
        full_scale_v: the board's full scale, V: a value with ``|v|`` above it is no
            measurement of the sheet (flagged ``FLAG_OUT_OF_RANGE``, left out of the image;
            the simulator's ADC gets this full scale); None: not stated, not checked.
        depth_m: a tank's depth, m (the electrodes a ring at mid-depth, as high as they are
            wide; :class:`~eit_skin.fem.elements.TankDepth`); None: a 2-D sheet.
    """

    name: str
    outline_kind: str
    outline: np.ndarray
    holes: tuple[np.ndarray, ...]
    electrodes: tuple[Electrode, ...]
    contact_impedance_ohm_m: float | tuple[float, ...]
    current_a: float
    protocol: ProtocolSpec
    material: Material
    mesh: MeshSpec
    solver: SolverSpec
    device: DeviceSpec = DEFAULT_DEVICE
    full_scale_v: float | None = None
    depth_m: float | None = None

    #: Fields that do not change the model: left out of the content hash.
    HASH_EXCLUDE: ClassVar[tuple[str, ...]] = ("device",)
    #: Keys added after patches were hashed: left out of the content hash at their default.
    HASH_ONLY_IF_SET: ClassVar[tuple[str, ...]] = ("full_scale_v", "depth_m")

    @property
    def n_electrodes(self) -> int:
        return len(self.electrodes)

    @property
    def perimeter_m(self) -> float:
        """Outline perimeter, m."""
        return float(geometry.arc_positions(self.outline)[-1])

    @property
    def area_m2(self) -> float:
        """Sheet area without holes, m^2."""
        return geometry.signed_area(self.outline) + sum(geometry.signed_area(h) for h in self.holes)

    @cached_property
    def measured_protocol(self) -> Protocol:
        """The expanded protocol as the board measures it (``device.negative_input_gain``)."""
        protocol = build_protocol(self.protocol, self.n_electrodes)
        return replace(protocol, negative_input_gain=self.device.negative_input_gain)

    @cached_property
    def content_hash(self) -> str:
        """sha256 hex digest of the layer's normalised content (cache key)."""
        content = _canonical(self)
        if self.device.negative_input_gain != 1.0:  # a device fact the model uses
            content["negative_input_gain"] = repr(self.device.negative_input_gain)
        return _hash(content)


DEFAULT_MOUNT_PARENT = "base_link"
"""Parent frame of a patch frame whose patch has no ``mount`` block (REP 105's robot base)."""


@dataclass(frozen=True)
class Mount:
    """Where the patch frame sits on the robot: its static transform from ``parent_frame``.

    Attributes:
        parent_frame: the robot frame the patch is mounted on (e.g. ``forearm_link``).
        xyz: translation of the patch frame in ``parent_frame``, metres [3].
        rpy: fixed-axis roll, pitch, yaw of the patch frame, radians [3] (URDF convention).
    """

    parent_frame: str = DEFAULT_MOUNT_PARENT
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True, eq=False)
class Patch:
    """A validated skin patch.

    Attributes:
        name: patch name.
        frame_id: ROS frame the sheet coordinates live in.
        layers: stacked sheets, in file order.
        placement: 3-D placement for visualisation.
        source: file the patch was read from (``"<dict>"`` for in-memory data).
        mount: the patch frame's pose on the robot (``mount`` block; default: identity in
            ``base_link``); the driver publishes it on /tf_static.
    """

    name: str
    frame_id: str
    layers: tuple[Layer, ...]
    placement: Placement
    source: str = "<dict>"
    mount: Mount = Mount()

    def layer(self, name: str | None = None) -> Layer:
        """The layer called ``name``; the first layer when ``name`` is None or empty.

        Raises:
            KeyError: no layer of that name (the message lists the patch's layers).
        """
        if not name:
            return self.layers[0]
        for layer in self.layers:
            if layer.name == name:
                return layer
        raise KeyError(f"patch {self.name!r} has no layer {name!r}; layers: {self.layer_names}")

    @property
    def layer_names(self) -> tuple[str, ...]:
        return tuple(layer.name for layer in self.layers)

    @cached_property
    def content_hash(self) -> str:
        """sha256 hex digest of the normalised content (not the file text or its path)."""
        content = {
            "name": self.name,
            "frame_id": self.frame_id,
            "layers": [layer.content_hash for layer in self.layers],
            "placement": _canonical(self.placement),
        }
        if self.mount != Mount():  # patches without a mount keep their earlier hash
            content["mount"] = _canonical(self.mount)
        return _hash(content)


def _canonical(obj: Any) -> Any:
    """JSON-able canonical form: floats as exact ``repr`` strings, arrays as nested lists."""
    if is_dataclass(obj):
        out = {"__type__": type(obj).__name__}
        later = getattr(type(obj), "HASH_ONLY_IF_SET", ())
        skip = getattr(type(obj), "HASH_EXCLUDE", ())
        for f in fields(obj):
            if f.name in skip:
                continue  # where it was written, not what it is
            value = getattr(obj, f.name)
            if f.name in later and value == f.default:
                continue  # a key added later, at its default: the hash it had before
            out[f.name] = _canonical(value)
        return out
    if isinstance(obj, np.ndarray):
        return {"shape": list(obj.shape), "values": [repr(float(v)) for v in obj.ravel()]}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, (bool, str)) or obj is None:
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return repr(float(obj))
    raise TypeError(f"cannot hash {type(obj).__name__}")


def _hash(content: Any) -> str:
    text = json.dumps(content, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()
