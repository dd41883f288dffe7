"""From a patch layer to its reconstruction: the one place the chain is built.

layer -> protocol -> mesh(es) -> forward model -> the layer's method
(:func:`eit_skin.inverse.dispatch.make_reconstructor`: ``one_step``, ``greit`` or
``gauss_newton``) -> image grid. :class:`LayerImager` puts the pieces together so that the
reconstruction node and the offline commands do exactly the same thing; :func:`forward_model`
is the layer's physics for everything that simulates it (the simulator, ``eit-skin tune``).

A layer with ``solver.accuracy_target`` is first resolved into an explicit layer (the coarsest
model meeting it, :mod:`eit_skin.pipeline.model_choice`, cached by content hash) by
:func:`resolve_layer`; everything below builds that layer.

Building needs a forward solve and a Jacobian; the relative Jacobian on the imaging mesh and
the chosen hyperparameter are cached on disk keyed by the layer's content hash, so a restart
with an unchanged config skips that work (``gauss_newton`` still sets up its forward model,
which it solves in every iteration).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from eit_skin.fem.elements import layer_depth
from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.image_grid import ImageGrid
from eit_skin.fem.mesh import Mesh, build_mesh
from eit_skin.frames import excluded_channels
from eit_skin.inverse.channel_noise import (
    ReferenceCheck,
    channel_scale,
    check_reference,
    estimate_channel_noise,
)
from eit_skin.inverse.dispatch import make_reconstructor
from eit_skin.inverse.electrode_faults import FaultTolerantReconstructor
from eit_skin.inverse.gauss_newton_method import GaussNewtonReconstructor
from eit_skin.inverse.hyperparameter import (
    MODEL_ERROR_SHARE,
    choose_for_model_error,
    reference_misfit,
)
from eit_skin.inverse.methods import (
    DEFAULT_NOISE_FIGURE,
    METHODS,
    METHODS_WITH_PRIOR,
    Reconstructor,
)
from eit_skin.inverse.one_step import ReconstructionMatrix, reference_scale
from eit_skin.io.npz import write_npz_atomic
from eit_skin.patch.material import RELATIVE_CHANGE_RANGE
from eit_skin.patch.model import Layer
from eit_skin.patch.protocol import Protocol
from eit_skin.pipeline.frame_plan import FramePlan, pressure_image
from eit_skin.pipeline.model_choice import ModelChoice, choose_model

#: Bumped whenever the cached quantities change meaning.
CACHE_VERSION = "2"


def default_cache_dir() -> Path:
    """``$EIT_SKIN_CACHE``, else ``$XDG_CACHE_HOME/eit_skin`` (``~/.cache/eit_skin``)."""
    if os.environ.get("EIT_SKIN_CACHE"):
        return Path(os.environ["EIT_SKIN_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "eit_skin"


def forward_model(layer: Layer, mesh: Mesh | None = None) -> ForwardModel:
    """The layer's forward model (protocol, contact impedance, current) on ``mesh``.

    ``mesh``: default the layer's forward mesh (``build_mesh(layer)``); a finer one to
    simulate data on.
    """
    return ForwardModel(
        build_mesh(layer) if mesh is None else mesh,
        layer.measured_protocol,
        layer.contact_impedance_ohm_m,
        layer.current_a,
        layer_depth(layer),
    )


def contact_patterns(layer: Layer) -> np.ndarray:
    """``[M, E]`` relative change of every channel per unit change of an electrode's contact.

    The change per unit contact impedance of each electrode on the homogeneous sheet (V/V
    per ohm m).

    ``dV/dz_l`` of the layer's forward model (:meth:`ForwardModel.contact_jacobian`) over
    ``|v|`` floored like a reference (:func:`~eit_skin.inverse.one_step.reference_scale`):
    the unit of the relative Jacobian, so times ``|v_ref|`` both are volts. An electrode's
    contact changing while nothing touches (sweat, creep, a connector) moves the frames
    along its column.
    """
    model = forward_model(layer)
    sheet = layer.material.sheet_conductance_s
    return model.contact_jacobian(sheet) / reference_scale(model.voltages(sheet))[:, None]


def choose_layer_model(layer: Layer, cache_dir: Path | str | None = "default") -> ModelChoice:
    """The coarsest model meeting the layer's ``solver.accuracy_target`` (cached in ``cache_dir``).

    Candidates are built by :meth:`LayerImager.build` and the phantoms simulated with
    :func:`forward_model`: the reconstruction's own chain and physics.

    Raises:
        PatchError: no candidate meets the target (names the file and key).
        ValueError: the layer has no accuracy target.
    """
    directory = default_cache_dir() if cache_dir == "default" else cache_dir
    return choose_model(
        layer, lambda explicit: LayerImager.build(explicit, None), forward_model, directory
    )


def resolve_layer(layer: Layer, cache_dir: Path | str | None = "default") -> Layer:
    """``layer`` as built: with an accuracy target, the explicit layer of its chosen model.

    A layer without ``solver.accuracy_target`` is returned as it is. The reconstruction node,
    the offline commands and ``eit-skin tune`` all build through this, so they share the
    chosen model (same content hash, same matrix cache).
    """
    if layer.solver.accuracy_target is None:
        return layer
    return choose_layer_model(layer, cache_dir).resolved


@dataclass(frozen=True, eq=False)
class Operator:
    """A layer's method, set up (:func:`build_operator`).

    Attributes:
        protocol: the layer's measurement protocol (``M`` channels).
        mesh: the imaging (inverse) mesh, ``N`` elements.
        reconstructor: the method (:class:`~eit_skin.inverse.methods.Reconstructor`).
        from_cache: whether the Jacobian and hyperparameter came from the disk cache.
        model_voltages: ``[M]`` homogeneous model voltages of the sheet, volts (the sign check
            of a reference, :func:`~eit_skin.inverse.channel_noise.check_reference`).
    """

    protocol: Protocol
    mesh: Mesh
    reconstructor: Reconstructor
    from_cache: bool = False
    model_voltages: np.ndarray | None = None


def build_operator(layer: Layer, cache_dir: Path | str | None = "default") -> Operator:
    """Set up the layer's ``solver.method`` (cached in ``cache_dir``; ``None``: no cache).

    The forward mesh is ``mesh.max_edge``; the imaging mesh ``mesh.inverse_max_edge`` (the
    forward mesh when unset), which also carries Gauss-Newton's unknowns. The hyperparameter
    is ``solver.hyperparameter``, else chosen for ``solver.noise_figure`` on the method's
    linear matrix (Gauss-Newton: its first linearised step, the one-step matrix with the
    same prior). A layer with ``solver.accuracy_target`` builds its chosen model
    (:func:`resolve_layer`).
    """
    layer = resolve_layer(layer, cache_dir)
    protocol = layer.measured_protocol
    inverse_edge = layer.mesh.inverse_max_edge_m
    inverse_mesh = build_mesh(layer, inverse_edge) if inverse_edge else build_mesh(layer)
    directory = default_cache_dir() if cache_dir == "default" else cache_dir
    path = None if directory is None else Path(directory) / f"{cache_key(layer)}.npz"
    forward = None
    if layer.solver.method == "gauss_newton" or path is None or not path.is_file():
        forward = _forward(layer, inverse_mesh)
    if path is not None and path.is_file():
        try:
            with np.load(path) as cached:
                jacobian = cached["jacobian"]
                h = float(cached["hyperparameter"])
                model_v = cached["model_voltages"]
            method = _method(layer, forward, inverse_mesh, jacobian, h)
            return Operator(protocol, inverse_mesh, method, True, model_v)
        except (OSError, KeyError, ValueError):
            pass  # unreadable or stale: rebuild and overwrite below
    if forward is None:
        forward = _forward(layer, inverse_mesh)
    method = _method(layer, forward, inverse_mesh, None, layer.solver.hyperparameter)
    model_v = forward.voltages(layer.material.sheet_conductance_s)
    if path is not None:
        _save_to_cache(
            path,
            jacobian=method.linearised.jacobian,
            hyperparameter=method.hyperparameter,
            model_voltages=model_v,
        )
    return Operator(protocol, inverse_mesh, method, model_voltages=model_v)


def with_method(layer: Layer, method: str) -> Layer:
    """``layer`` with ``solver.method = method`` (e.g. a command's ``--method``).

    ``hyperparameter`` and ``noise_figure`` were chosen for the layer's linear matrix: they
    are kept between ``one_step`` and ``gauss_newton`` (whose first step is that matrix) and
    reset to ``None`` and the new method's default
    (:data:`~eit_skin.inverse.methods.DEFAULT_NOISE_FIGURE`) when switching to or from the
    trained ``greit`` matrix.
    """
    solver = layer.solver
    if method not in METHODS:
        raise ValueError(f"method: unknown {method!r}; expected one of {METHODS}")
    if method == solver.method:
        return layer
    if {method, solver.method} <= set(METHODS_WITH_PRIOR):
        return replace(layer, solver=replace(solver, method=method))
    new = replace(
        solver, method=method, hyperparameter=None, noise_figure=DEFAULT_NOISE_FIGURE[method]
    )
    return replace(layer, solver=new)


@dataclass(frozen=True)
class ReferenceReport:
    """What :meth:`LayerImager.use_reference` found and chose.

    Attributes:
        check: the reference's excluded channels and why.
        noise_source: how the channel noise was measured; None: not measured (unweighted).
        median_noise: median relative noise of one frame's ``dv`` over the used channels.
        weighted: channels whose noise is above the median (down-weighted).
        hyperparameter: the ``h`` in use; ``chosen``: whether it was chosen for the measured
            noise and model error (False: ``solver.hyperparameter`` fixed it, or the method
            takes no weights).
        model_misfit: the reference's relative misfit to the homogeneous model
            (:func:`~eit_skin.inverse.hyperparameter.reference_misfit`); NaN: not measured.
        for_model_error: whether the model-error rule, not the noise figure, set ``h``.
        equal_weights: whether ``solver.channel_weights: equal`` weighted every channel alike
            (``weighted`` is then 0).
    """

    check: ReferenceCheck
    noise_source: str | None
    median_noise: float
    weighted: int
    hyperparameter: float
    chosen: bool
    model_misfit: float = float("nan")
    for_model_error: bool = False
    equal_weights: bool = False

    def lines(self) -> list[str]:
        """Human-readable summary, one fact per line."""
        out = [self.check.summary]
        if self.noise_source is None:
            out.append("channel noise: not measured (channels weighted equally)")
        else:
            weights = (
                "channels weighted equally (solver.channel_weights)"
                if self.equal_weights
                else f"{self.weighted} channels noisier (down-weighted)"
            )
            out.append(
                f"channel noise: {self.noise_source}; median {self.median_noise:.3g} of the "
                f"reference per frame, {weights}"
            )
        if np.isfinite(self.model_misfit):
            out.append(f"reference misfit to the model {self.model_misfit:.1%}")
        how = "fixed"
        if self.chosen:
            rule = "model error" if self.for_model_error else "measured noise"
            how = f"chosen for the {rule}"
        out.append(f"hyperparameter {self.hyperparameter:.4g} ({how})")
        return out


@dataclass
class LayerImager:
    """Reconstruction of one layer: frames (V) -> relative change -> physical images.

    Attributes:
        layer: the layer's validated config.
        protocol: its measurement protocol (M channels).
        mesh: the inverse mesh the images are reconstructed on.
        matrix: the method's linear matrix (``one_step``, ``greit``: the method itself;
            ``gauss_newton``: its first linearised step).
        grid: element -> pixel interpolation (``H x W``), NaN outside the sheet.
        from_cache: whether the Jacobian came from the disk cache.
        reconstructor: the layer's ``solver.method`` (default: ``matrix``).
        model_voltages: ``[M]`` homogeneous model voltages (reference sign check), if known.
        reference_excluded: bool ``[M]`` channels left out because of the reference
            (:meth:`use_reference`); None before.
        signs: ``[M]`` +-1 the frames and references are multiplied by before imaging: the
            homogeneous model's signs for a device reporting magnitudes
            (``protocol.values: magnitude``), else None.
        channel_noise_v: ``[M]`` the noise of one frame per channel, V, that
            :meth:`use_reference` measured (NaN: unknown); None before or when not measurable.
    """

    layer: Layer
    protocol: Protocol
    mesh: Mesh
    matrix: ReconstructionMatrix
    grid: ImageGrid
    from_cache: bool = False
    reconstructor: Reconstructor = None  # type: ignore[assignment]  # None: ``matrix``
    model_voltages: np.ndarray | None = None
    reference_excluded: np.ndarray | None = None
    signs: np.ndarray | None = field(default=None, init=False)
    channel_noise_v: np.ndarray | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        if self.reconstructor is None:
            self.reconstructor = self.matrix
        self._unweighted = self.reconstructor
        self._plan: FramePlan | None = None
        self._plan_of: Reconstructor | None = None  # the reconstructor _plan was built for
        self.signs = None
        if self.protocol.magnitude:
            if self.model_voltages is None:
                raise ValueError("values: magnitude needs the model voltages for the signs")
            self.signs = np.where(np.asarray(self.model_voltages) < 0, -1.0, 1.0)

    def _signed(self, values: np.ndarray | None) -> np.ndarray | None:
        """``values`` [..., M] with the model's signs for a magnitude device (else as given)."""
        if values is None or self.signs is None:
            return values
        return np.asarray(values, dtype=np.float64) * self.signs

    def use_reference(
        self,
        reference: np.ndarray,
        reference_frames: np.ndarray | None = None,
        frames: np.ndarray | None = None,
        model_error_share: float = MODEL_ERROR_SHARE,
    ) -> ReferenceReport:
        """Check a reference ``[M]`` V and weight the channels by their measured noise.

        The one rule, online and offline (:mod:`eit_skin.inverse.channel_noise`): channels
        with an unusable reference value are left out of every later image; the noise of
        ``reference_frames`` ``[K, M]`` V (else of ``frames`` ``[T, M]`` V, else of the
        reference's reciprocity) weights the channels (``one_step``/``greit``; Gauss-Newton is
        not weighted; ``solver.channel_weights: equal`` weights every channel alike, as
        EIDORS and pyEIT) and the hyperparameter is re-chosen, unless ``solver.hyperparameter``
        fixes it, as the larger of the one for the layer's noise figure on that measured
        noise and the one for the model error (``model_error_share`` of the reference's
        misfit to the homogeneous model: :mod:`eit_skin.inverse.hyperparameter`; 0 turns
        that rule off). One ``M x M`` factorisation per trial, no Jacobian. Gauss-Newton's
        warm start is reset: the next frame's fit starts from ``sigma0``.

        Raises:
            UnusableReferenceError: (a ValueError) the reference cannot be imaged against.
        """
        reference = self._signed(reference)
        reference_frames, frames = self._signed(reference_frames), self._signed(frames)
        check = check_reference(reference, self.protocol, self.model_voltages)
        self.reference_excluded = check.excluded
        base = self._unweighted
        if isinstance(base, GaussNewtonReconstructor):
            base.reset()  # the last solution belongs to the old reference
        noise = estimate_channel_noise(reference, self.protocol, reference_frames, frames)
        self.channel_noise_v = None if noise is None else noise.sigma_v
        if noise is None or not isinstance(base, ReconstructionMatrix):
            self.reconstructor = base
            self.matrix = base.linearised
            return ReferenceReport(check, None, float("nan"), 0, base.hyperparameter, False)
        relative = noise.relative(reference)
        usable = ~check.excluded & np.isfinite(relative)
        equal = self.layer.solver.channel_weights == "equal"
        scale = np.ones_like(relative) if equal else channel_scale(relative, usable)
        fixed = self.layer.solver.hyperparameter
        target = None
        if fixed is None:
            target = self.layer.solver.noise_figure or DEFAULT_NOISE_FIGURE[base.method]
        weighted = base.with_channel_scale(scale, noise_figure=target)
        misfit = float("nan")
        for_model_error = False
        if self.model_voltages is not None:
            misfit = reference_misfit(reference, self.model_voltages, usable)
        if fixed is None and model_error_share > 0 and np.isfinite(misfit):
            h_model = choose_for_model_error(weighted.gram[0], model_error_share * misfit)
            if h_model > weighted.hyperparameter:
                weighted = weighted.with_hyperparameter(h_model)
                for_model_error = True
        self.reconstructor = self.matrix = weighted
        median = float(np.median(relative[usable])) if usable.any() else float("nan")
        n_weighted = int(np.count_nonzero(scale[usable] > 1.0))
        return ReferenceReport(
            check,
            noise.source,
            median,
            n_weighted,
            weighted.hyperparameter,
            fixed is None,
            misfit,
            for_model_error,
            equal,
        )

    @classmethod
    def build(cls, layer: Layer, cache_dir: Path | str | None = "default") -> LayerImager:
        """Build (or load from ``cache_dir``; ``None`` disables the cache) the chain of a layer.

        A layer with ``solver.accuracy_target`` builds its chosen model (:func:`resolve_layer`);
        ``imager.layer`` is then that explicit layer.

        >>> from eit_skin.patch.loading import load_patch
        >>> from eit_skin.resources import config_path
        >>> imager = LayerImager.build(load_patch(config_path("face")).layers[0])
        >>> imager.method, imager.n_measurements, imager.grid.shape  # [H, W] pixels
        ('greit', 208, (64, 45))
        """
        layer = resolve_layer(layer, cache_dir)
        op = build_operator(layer, cache_dir)
        grid = ImageGrid.build(op.mesh, layer.solver.image_pixels)
        rec = op.reconstructor
        return cls(
            layer, op.protocol, op.mesh, rec.linearised, grid, op.from_cache, rec, op.model_voltages
        )

    @property
    def method(self) -> str:
        """The method imaging the frames (:data:`eit_skin.inverse.methods.METHODS`)."""
        return self.reconstructor.method

    @property
    def n_measurements(self) -> int:
        return self.protocol.n_measurements

    def fault_tolerant(self) -> FaultTolerantReconstructor:
        """A reconstructor that also detects and leaves out faulty electrodes."""
        return FaultTolerantReconstructor(self.reconstructor, self.protocol)

    def relative_change(
        self,
        frames: np.ndarray,
        reference: np.ndarray,
        flags: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames ``[T, M]`` or ``[M]`` volts -> relative conductivity change per element.

        Channels flagged saturated/invalid (``flags`` uint8 ``[M]``, ``EitFrame`` bits) and
        channels that are NaN in a frame or the reference are left out, never imaged
        (one-step/GREIT: cached reduced matrices; Gauss-Newton: fitted without them, one
        fit per frame), as are the channels :meth:`use_reference` excluded.
        """
        return self.reconstructor.reconstruct(
            self._signed(frames), self._signed(reference), excluded=self._excluded(flags)
        )

    def _excluded(self, flags: np.ndarray | None) -> np.ndarray | None:
        """Channels left out: the reference's and the flagged ones; None when none."""
        excluded = self.reference_excluded
        if flags is not None and np.size(flags):
            flagged = excluded_channels(flags, self.n_measurements)
            excluded = flagged if excluded is None else excluded | flagged
        if excluded is not None and not excluded.any():
            excluded = None
        return excluded

    @property
    def frame_plan(self) -> FramePlan | None:
        """The plan of this layer's common frames (:mod:`eit_skin.pipeline.frame_plan`).

        None unless a pressure layer with a linear matrix over every channel; built again
        when the reconstructor changes (:meth:`use_reference` re-weights it).
        """
        rec = self.reconstructor
        if self._plan_of is not rec:
            pascals = self.layer.material.linear_pascals  # 0: no linear pressure unit
            self._plan = FramePlan.build(rec, self.grid, pascals, self.signs)
            self._plan_of = rec
        return self._plan

    def frame_images(
        self, frames: np.ndarray, reference: np.ndarray, flags: np.ndarray | None = None
    ) -> np.ndarray:
        """Frames ``[M]``/``[T, M]`` V -> physical images ``[H, W]``/``[T, H, W]`` (float32).

        ``images(physical(relative_change(...)))``; one frame: :meth:`physical_image` of its
        relative change, the node's numbers bit for bit.
        """
        values = self.relative_change(frames, reference, flags)
        if values.ndim == 1:
            return self.physical_image(values)
        return self.images(self.physical(values))

    def images(self, element_values: np.ndarray) -> np.ndarray:
        """Element values ``[N]``/``[T, N]`` -> float32 images ``[H, W]``/``[T, H, W]``."""
        return self.grid.to_image(element_values)

    def physical_image(self, relative_change: np.ndarray) -> np.ndarray:
        """One frame's relative change ``[N]`` -> its physical image ``[H, W]`` float32.

        Bit for bit ``images(physical(relative_change))``; for pressure (a linear unit) the
        planned step's image (:func:`~eit_skin.pipeline.frame_plan.pressure_image`).
        """
        material = self.layer.material
        v = np.asarray(relative_change)
        if not material.linear_pascals or v.shape != (self.mesh.n_triangles,):
            return self.images(self.physical(v))
        grid = self.grid
        return pressure_image(v, material.linear_pascals, grid.pixel_owner, grid.shape)

    def physical(self, relative_images: np.ndarray) -> np.ndarray:
        """Relative change -> the layer's quantity (Pa for pressure, strain for stretch).

        Pointwise, so it applies to element values ``[N]`` as well as to images; the node
        converts the ``N`` element values and then images them (fewer values than pixels).

        Relative changes outside :data:`~eit_skin.patch.material.RELATIVE_CHANGE_RANGE` (a
        conductance that all but vanished, or rose more than tenfold: beyond what the
        linearised reconstruction can claim, e.g. the channels of a dead electrode before
        the fault check left them out) are clipped to its ends, so the physical image stays
        within :attr:`Material.physical_range <eit_skin.patch.material.Material.physical_range>`;
        NaN (outside the sheet) stays NaN.
        """
        low, high = RELATIVE_CHANGE_RANGE
        clipped = np.maximum(relative_images, low)  # two ufuncs: np.clip's wrapper costs more
        np.minimum(clipped, high, out=clipped)
        return self.layer.material.to_physical(clipped).astype(np.float32)


def cache_key(layer: Layer) -> str:
    """File stem of a layer's cached matrix: content hash and cache version."""
    digest = hashlib.sha256(f"{CACHE_VERSION}:{layer.content_hash}".encode()).hexdigest()
    return f"{layer.name}-{digest[:24]}"


def _forward(layer: Layer, inverse_mesh: Mesh) -> ForwardModel:
    """Forward model on the layer's forward mesh (the inverse mesh when it has no other)."""
    return forward_model(layer, inverse_mesh if layer.mesh.inverse_max_edge_m is None else None)


def _method(
    layer: Layer,
    forward: ForwardModel | None,
    mesh: Mesh,
    jacobian: np.ndarray | None,
    hyperparameter: float | None,
) -> Reconstructor:
    """The layer's ``solver`` as :func:`~eit_skin.inverse.dispatch.make_reconstructor` arguments."""
    solver = layer.solver
    return make_reconstructor(
        solver.method,
        forward,
        jacobian=jacobian,
        mesh=mesh,
        prior=solver.prior if solver.method in METHODS_WITH_PRIOR else None,
        hyperparameter=hyperparameter,
        noise_figure=solver.noise_figure,
        sigma0=layer.material.sheet_conductance_s,
        max_iterations=solver.max_iterations if solver.method == "gauss_newton" else None,
    )


def _save_to_cache(path: Path, **arrays: np.ndarray | float) -> None:
    """Store a cache entry atomically; a read-only cache only costs the rebuild next time."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_npz_atomic(path, **arrays)
    except OSError:
        pass
