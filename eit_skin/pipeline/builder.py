"""From a patch layer's raw frames to images: the whole reconstruction chain of one layer.

:class:`LayerImager` puts together the pieces the patch config asks for - mesh, protocol,
forward model, one-step reconstruction matrix (with its electrode-fault handling), image
grid and material - so that the reconstruction node and the offline commands do exactly the
same thing. Building the matrix needs a forward solve and a Jacobian; the relative Jacobian
and the chosen hyperparameter are cached on disk keyed by the layer's content hash, so a
restart with an unchanged config skips that work.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eit_skin.fem.forward import ForwardModel
from eit_skin.fem.image_grid import ImageGrid
from eit_skin.fem.mesh import Mesh, build_mesh
from eit_skin.frames import excluded_channels
from eit_skin.inverse.electrode_faults import FaultTolerantReconstructor
from eit_skin.inverse.one_step import ReconstructionMatrix
from eit_skin.io.npz import write_npz_atomic
from eit_skin.patch.model import Layer
from eit_skin.patch.protocol import Protocol, build_protocol

#: Bumped whenever the cached quantities change meaning.
CACHE_VERSION = "1"

#: Floor of the relative conductivity change before the physical conversion.
MIN_RELATIVE_CHANGE = -0.9


def default_cache_dir() -> Path:
    """``$EIT_SKIN_CACHE``, else ``$XDG_CACHE_HOME/eit_skin`` (``~/.cache/eit_skin``)."""
    if os.environ.get("EIT_SKIN_CACHE"):
        return Path(os.environ["EIT_SKIN_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "eit_skin"


@dataclass
class LayerImager:
    """Reconstruction of one layer: frames (V) -> relative change -> physical images.

    Attributes:
        layer: the layer's validated config.
        protocol: its measurement protocol (M channels).
        mesh: the inverse mesh the images are reconstructed on.
        matrix: the one-step reconstruction matrix.
        grid: element -> pixel interpolation (``H x W``), NaN outside the sheet.
        from_cache: whether the Jacobian came from the disk cache.
    """

    layer: Layer
    protocol: Protocol
    mesh: Mesh
    matrix: ReconstructionMatrix
    grid: ImageGrid
    from_cache: bool = False

    @classmethod
    def build(cls, layer: Layer, cache_dir: Path | str | None = "default") -> LayerImager:
        """Build (or load from ``cache_dir``; ``None`` disables the cache) the chain of a layer."""
        protocol = build_protocol(layer.protocol, layer.n_electrodes)
        inverse_edge = layer.mesh.inverse_max_edge_m
        inverse_mesh = build_mesh(layer, inverse_edge) if inverse_edge else build_mesh(layer)
        solver = layer.solver
        directory = default_cache_dir() if cache_dir == "default" else cache_dir
        path = None if directory is None else Path(directory) / f"{cache_key(layer)}.npz"
        if path is not None and path.is_file():
            try:
                with np.load(path) as cached:
                    jacobian = cached["jacobian"]
                    h = float(cached["hyperparameter"])
                matrix = ReconstructionMatrix.from_jacobian(
                    jacobian, inverse_mesh, _matrix_kind(solver), h
                )
                grid = ImageGrid.build(inverse_mesh, solver.image_pixels)
                return cls(layer, protocol, inverse_mesh, matrix, grid, from_cache=True)
            except (OSError, KeyError, ValueError):
                pass  # unreadable or stale: rebuild and overwrite below
        forward_mesh = build_mesh(layer) if inverse_edge else inverse_mesh
        forward = ForwardModel(
            forward_mesh, protocol, layer.contact_impedance_ohm_m, layer.current_a
        )
        matrix = ReconstructionMatrix.build(
            forward,
            prior=_matrix_kind(solver),
            hyperparameter=solver.hyperparameter,
            sigma0=layer.material.sheet_conductance_s,
            inverse_mesh=None if inverse_edge is None else inverse_mesh,
            noise_figure=solver.noise_figure,
        )
        if path is not None:
            _save_to_cache(path, jacobian=matrix.jacobian, hyperparameter=matrix.hyperparameter)
        grid = ImageGrid.build(inverse_mesh, solver.image_pixels)
        return cls(layer, protocol, inverse_mesh, matrix, grid)

    @property
    def n_measurements(self) -> int:
        return self.protocol.n_measurements

    def fault_tolerant(self) -> FaultTolerantReconstructor:
        """A reconstructor that also detects and leaves out faulty electrodes."""
        return FaultTolerantReconstructor(self.matrix, self.protocol)

    def relative_change(
        self,
        frames: np.ndarray,
        reference: np.ndarray,
        flags: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames ``[T, M]`` or ``[M]`` volts -> relative conductivity change per element.

        Channels flagged saturated/invalid (``flags`` uint8 ``[M]``, ``EitFrame`` bits) and
        channels that are NaN in a frame or the reference are left out (cached reduced
        matrices), never imaged.
        """
        excluded = None
        if flags is not None and np.size(flags):
            excluded = excluded_channels(flags, self.n_measurements)
        return self.matrix.reconstruct(frames, reference, excluded=excluded)

    def images(self, element_values: np.ndarray) -> np.ndarray:
        """Element values ``[N]``/``[T, N]`` -> float32 images ``[H, W]``/``[T, H, W]``."""
        return self.grid.to_image(element_values)

    def physical(self, relative_images: np.ndarray) -> np.ndarray:
        """Relative change -> the layer's quantity (Pa for pressure, strain for stretch).

        Pointwise, so it applies to element values ``[N]`` as well as to images; the node
        converts the ``N`` element values and then images them (fewer values than pixels).

        Relative changes below :data:`MIN_RELATIVE_CHANGE` (a conductance that all but
        vanished, beyond what the linearised reconstruction can claim) are clipped there,
        so the physical image stays finite; NaN (outside the sheet) stays NaN.
        """
        clipped = np.maximum(relative_images, MIN_RELATIVE_CHANGE)
        return self.layer.material.to_physical(clipped).astype(np.float32)


def cache_key(layer: Layer) -> str:
    """File stem of a layer's cached matrix: content hash and cache version."""
    digest = hashlib.sha256(f"{CACHE_VERSION}:{layer.content_hash}".encode()).hexdigest()
    return f"{layer.name}-{digest[:24]}"


def _save_to_cache(path: Path, **arrays: np.ndarray | float) -> None:
    """Store a cache entry atomically; a read-only cache only costs the rebuild next time."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_npz_atomic(path, **arrays)
    except OSError:
        pass


def _matrix_kind(solver) -> str:
    """The one-step matrix of a solver: ``"greit"`` for method greit, else its prior."""
    return "greit" if solver.method == "greit" else solver.prior
