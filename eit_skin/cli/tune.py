"""``eit-skin tune``: choose a layer's regularisation by noise figure, optionally store it.

Builds the layer's chain exactly as the reconstruction does (:mod:`eit_skin.pipeline.builder`:
forward mesh, inverse mesh, ``solver.method`` and prior), with the hyperparameter ``h`` whose
noise figure equals the target (:func:`eit_skin.inverse.hyperparameter.choose_by_noise_figure`
on the method's linear matrix - for ``gauss_newton`` its first linearised step; the target is
``--noise-figure`` or the layer's ``solver.noise_figure``), rounds ``h`` to 4 significant
digits and prints it with the figures the linear matrix gives: the noise figure, and the GREIT
position error, resolution and ringing on about a dozen small simulated targets over the sheet,
centres at least 1.5 target radii from its outline (radius 10 % of the sheet's equivalent
radius ``R``, conductance x2, 1 % noise, fixed seed), simulated on a finer mesh than the
reconstruction's (edge at most 40 % of the target radius, so every target covers several
triangles).

A layer with ``solver.accuracy_target`` (instead of mesh sizes) first gets its model chosen
(:func:`eit_skin.pipeline.builder.choose_layer_model`: the coarsest forward and inverse meshes,
pixel count and Gauss-Newton iteration count meeting the target on the package's phantom set,
cached by content hash, so the node builds the same model); the ladder of candidates with
each one's errors and cost, and the choice, are printed first, and the hyperparameter is then
tuned on the chosen model.

``--write`` stores ``hyperparameter: <h>`` in that layer's ``solver`` mapping by editing the
file's text at the positions PyYAML reports (a flow mapping ``{...}`` gets a new entry before
its closing brace, a block mapping a new line; an existing value is replaced), so comments
and formatting elsewhere are kept. The edited text is validated (``load_patch``: same patch
apart from that value) before it atomically replaces the file. Shipped configs are only
written when given by path, never by name.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eit_skin.cli.errors import USER_ERRORS, report_error
from eit_skin.cli.options import add_patch_options, add_write_option, patch_file

#: Significant digits of the stored hyperparameter.
DIGITS = 4
#: Simulated targets: count, radius (fraction of the equivalent radius), conductance ratio.
N_TARGETS = 12
TARGET_RADIUS = 0.10
TARGET_CONTRAST = 2.0
NOISE = 0.01
#: Minimum distance of a target centre from the outline and holes, in target radii.
EDGE_CLEARANCE = 1.5
#: Data mesh edge: this fraction of the forward mesh edge, at most this fraction of the target
#: radius.
DATA_MESH_FRACTION = 0.7
DATA_MESH_PER_TARGET_RADIUS = 0.4


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser)
    parser.add_argument(
        "--noise-figure",
        type=float,
        default=None,
        metavar="NF",
        help="target noise figure (default: the layer's solver.noise_figure)",
    )
    parser.add_argument(
        "--frames",
        type=Path,
        default=None,
        metavar="IN.npz",
        help="a recording (eit-skin reconstruct's input; optional reference_frames [K, M]): "
        "show its reference check, measured channel noise and the hyperparameter chosen on it",
    )
    add_write_option(parser, "the chosen value as solver.hyperparameter")


def run(args: argparse.Namespace) -> int:
    try:
        path = patch_file(args)
        for line in model_choice(path, args.layer):
            print(line)
        result = tune_layer(path, args.layer, args.noise_figure)
        print(result.summary())
        if args.frames is not None:
            for line in measured(path, result.layer, args.frames):
                print(f"{args.frames}: {line}")
        if args.write:
            write_hyperparameter(path, result.layer, result.hyperparameter)
            print(f"wrote hyperparameter: {result.text} to {path} (layer {result.layer}, solver)")
        else:
            print("not written (add --write to store it as solver.hyperparameter)")
    except USER_ERRORS as exc:
        return report_error("tune", exc)
    return 0


def model_choice(path: Path, layer_name: str | None) -> list[str]:
    """The accuracy target's ladder and choice (cached), or nothing for explicit mesh sizes."""
    from eit_skin.patch.loading import load_patch
    from eit_skin.pipeline.builder import choose_layer_model

    patch = load_patch(path)
    layer = patch.layer(layer_name)
    if layer.solver.accuracy_target is None:
        return []
    return choose_layer_model(layer).lines()


def measured(path: Path, layer_name: str, frames_path: Path) -> list[str]:
    """What the pipeline measures and chooses on a recording (``LayerImager.use_reference``)."""
    import numpy as np

    from eit_skin.io.npz import FramesNpzReader
    from eit_skin.patch.loading import load_patch
    from eit_skin.pipeline.builder import LayerImager

    if not frames_path.is_file():
        raise ValueError(f"{frames_path}: no such file")
    imager = LayerImager.build(load_patch(path).layer(layer_name))
    select = imager.protocol.select  # the device's layout, complex part
    reader = FramesNpzReader(frames_path, convert=select)
    reference, frames = reader.reference, reader.head(reader.n_frames)
    with np.load(frames_path) as raw:
        repeated = raw.get("reference_frames")
    if repeated is not None:
        repeated = select(repeated, f"{frames_path}: 'reference_frames'")
        if repeated.ndim != 2:
            raise ValueError(f"{frames_path}: 'reference_frames' must be [K, {reference.size}]")
    return imager.use_reference(reference, repeated, frames).lines()


@dataclass(frozen=True)
class Tuning:
    """The chosen hyperparameter of one layer and what it gives.

    Attributes:
        layer: layer name.
        method: the layer's ``solver.method``, with its prior where it has one
            (``"one_step, prior laplace"``).
        target_noise_figure: the noise figure asked for.
        hyperparameter: chosen ``h`` rounded to :data:`DIGITS` significant digits.
        text: ``h`` as written to the file.
        noise_figure: noise figure at the rounded ``h``.
        n_elements: inverse-mesh elements.
        radius_m: equivalent radius ``R`` of the sheet, metres.
        max_position_error: over the simulated targets, fraction of ``R``.
        mean_position_error: fraction of ``R``.
        mean_resolution: GREIT resolution (dimensionless).
        mean_ringing: GREIT ringing (dimensionless).
        n_targets: simulated targets.
        data_triangles: triangles of the mesh the targets were simulated on.
    """

    layer: str
    method: str
    target_noise_figure: float
    hyperparameter: float
    text: str
    noise_figure: float
    n_elements: int
    radius_m: float
    max_position_error: float
    mean_position_error: float
    mean_resolution: float
    mean_ringing: float
    n_targets: int
    data_triangles: int

    def summary(self) -> str:
        return (
            f"layer {self.layer}: method {self.method}, {self.n_elements} elements, target noise "
            f"figure {self.target_noise_figure:g}\n"
            f"hyperparameter {self.text} (noise figure {self.noise_figure:.4g})\n"
            f"{self.n_targets} simulated targets (radius {TARGET_RADIUS:.0%} R, conductance "
            f"x{TARGET_CONTRAST:g}, {NOISE:.0%} noise, {self.data_triangles}-triangle data mesh; "
            f"R = {self.radius_m * 1e3:.1f} mm): position error max "
            f"{self.max_position_error:.2%} R, mean {self.mean_position_error:.2%} R; "
            f"resolution {self.mean_resolution:.3f}; ringing {self.mean_ringing:.2f}"
        )


def tune_layer(path: Path, layer_name: str | None, noise_figure: float | None) -> Tuning:
    """Choose the hyperparameter of a layer of the patch file ``path`` (see module doc)."""
    from dataclasses import replace

    import numpy as np

    from eit_skin.fem.mesh import build_mesh
    from eit_skin.inverse.figures_of_merit import figures_of_merit
    from eit_skin.inverse.greit import equivalent_radius, target_centres
    from eit_skin.inverse.hyperparameter import noise_figure as nf_of
    from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE
    from eit_skin.inverse.one_step import relative_difference
    from eit_skin.patch.loading import load_patch
    from eit_skin.pipeline.builder import LayerImager, forward_model, resolve_layer

    patch = load_patch(path)
    layer = patch.layer(layer_name)
    layer = resolve_layer(layer)  # an accuracy target: its chosen model (cached)
    solver = layer.solver
    if noise_figure is None:
        noise_figure = solver.noise_figure or DEFAULT_NOISE_FIGURE[solver.method]
    target_nf = float(noise_figure)
    if not (np.isfinite(target_nf) and target_nf > 0):
        raise ValueError(f"--noise-figure must be > 0, got {noise_figure}")
    sigma0 = layer.material.sheet_conductance_s
    # the reconstruction's own chain, with h chosen for the target noise figure
    untuned = replace(solver, hyperparameter=None, noise_figure=target_nf)
    imager = LayerImager.build(replace(layer, solver=untuned), cache_dir=None)
    inverse_mesh, grid = imager.mesh, imager.grid
    text = f"{imager.matrix.hyperparameter:.{DIGITS}g}"
    rm = imager.matrix.with_hyperparameter(float(text))

    # simulated targets on a finer, different mesh
    radius = equivalent_radius(inverse_mesh)
    data_edge = min(
        DATA_MESH_FRACTION * layer.mesh.max_edge_m,
        DATA_MESH_PER_TARGET_RADIUS * TARGET_RADIUS * radius,
    )
    data_mesh = build_mesh(layer, data_edge)
    data = forward_model(layer, data_mesh)
    centres = target_centres(inverse_mesh, 2 * N_TARGETS)
    # targets not cut by the outline (for a disk: centres within 0.85 R); they may overlap holes
    clear = _outline_distance(layer.outline, centres) >= EDGE_CLEARANCE * TARGET_RADIUS * radius
    centres = centres[clear]
    if centres.shape[0] == 0:
        raise ValueError(f"layer {layer.name}: no room for a simulated target")
    v_ref = data.voltages(sigma0)
    rng = np.random.default_rng(0)
    frames = []
    for c in centres:
        sigma = np.full(data_mesh.n_triangles, sigma0)
        inside = np.linalg.norm(data_mesh.centroids - c, axis=1) < TARGET_RADIUS * radius
        sigma[inside] *= TARGET_CONTRAST
        v = data.voltages(sigma)
        frames.append(v + rng.normal(0.0, NOISE * np.sqrt(np.mean((v - v_ref) ** 2)), v.size))
    images = grid.to_image(rm.solve(relative_difference(np.stack(frames), v_ref)))
    merits = [
        figures_of_merit(im, grid.x, grid.y, c, sign=1.0)
        for im, c in zip(images, centres, strict=True)
    ]
    pe = np.array([f.position_error_m for f in merits]) / radius
    return Tuning(
        layer=layer.name,
        method=solver.method
        if solver.method == "greit"
        else f"{solver.method}, prior {solver.prior}",
        target_noise_figure=target_nf,
        hyperparameter=float(text),
        text=text,
        noise_figure=nf_of(rm),
        n_elements=rm.n_elements,
        radius_m=radius,
        max_position_error=float(pe.max()),
        mean_position_error=float(pe.mean()),
        mean_resolution=float(np.mean([f.resolution for f in merits])),
        mean_ringing=float(np.mean([f.ringing for f in merits])),
        n_targets=len(merits),
        data_triangles=data_mesh.n_triangles,
    )


def _outline_distance(outline: Any, points: Any) -> Any:
    """``[K]`` distance (m) of ``points`` ``[K, 2]`` to the closed polygon ``outline`` (m)."""
    import numpy as np

    a = np.asarray(outline, dtype=np.float64)
    ab = np.roll(a, -1, axis=0) - a  # [E, 2]
    ap = points[:, None, :] - a[None]  # [K, E, 2]
    s = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(ap - s[..., None] * ab, axis=-1).min(axis=1)


# ------------------------------------------------------------------------ writing the file
def write_hyperparameter(path: Path, layer_name: str, value: float) -> None:
    """Store ``solver.hyperparameter: value`` of layer ``layer_name`` in the file ``path``.

    Only the text of that entry changes; the result is validated with ``load_patch`` and then
    atomically replaces the file.
    """
    from eit_skin.patch.loading import load_patch

    path = Path(path)
    before = load_patch(path)
    text = path.read_text(encoding="utf-8")
    new_text = set_solver_hyperparameter(text, layer_name, value, source=str(path))
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".yaml", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(new_text)
        after = load_patch(tmp)
        _check_only_hyperparameter_changed(before, after, layer_name, value, str(path))
        os.chmod(tmp, path.stat().st_mode & 0o7777)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _check_only_hyperparameter_changed(before, after, layer_name, value, source) -> None:
    """Raise unless ``after`` is ``before`` with that one hyperparameter set (content hashes)."""
    from dataclasses import replace

    got = after.layer(layer_name).solver.hyperparameter
    if got != float(value):
        raise ValueError(f"{source}: edit failed, read back hyperparameter {got}, not {value}")
    expected = replace(
        before,
        layers=tuple(
            replace(lay, solver=replace(lay.solver, hyperparameter=float(value)))
            if lay.name == layer_name
            else lay
            for lay in before.layers
        ),
    )
    if expected.content_hash != after.content_hash:
        raise ValueError(f"{source}: edit changed more than the hyperparameter; not written")


def set_solver_hyperparameter(
    text: str, layer_name: str, value: float, source: str = "<text>"
) -> str:
    """``text`` (patch YAML) with ``layers[name == layer_name].solver.hyperparameter = value``.

    Raises:
        ValueError: the text has no ``layers`` sequence or no such layer.
    """
    number = f"{float(value):.{DIGITS}g}"
    return set_layer_entry(text, layer_name, "solver.hyperparameter", number, source)


def set_layer_entry(
    text: str, layer_name: str, entry: str, value_text: str, source: str = "<text>"
) -> str:
    """``text`` (patch YAML) with ``layers[name == layer_name].<entry>: value_text``.

    ``entry`` is ``"<section>.<key>"``, e.g. ``"solver.hyperparameter"``. Only that entry's
    text changes (added to the section, or the section added to the layer, when missing), so
    comments and formatting elsewhere are kept.

    Raises:
        ValueError: the text has no ``layers`` sequence, no such layer, or the section is
            not a mapping.
    """
    import yaml

    section, key = entry.split(".")
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    layers = _get(root, "layers")
    if not isinstance(layers, yaml.SequenceNode):
        raise ValueError(f"{source}: no 'layers' list")
    layer = next(
        (
            item
            for item in layers.value
            if isinstance(item, yaml.MappingNode)
            and getattr(_get(item, "name"), "value", None) == layer_name
        ),
        None,
    )
    if layer is None:
        raise ValueError(f"{source}: no layer named {layer_name!r}")
    mapping = _get(layer, section)
    if mapping is None:
        return _insert_entry(text, layer, section, f"{{{key}: {value_text}}}")
    if not isinstance(mapping, yaml.MappingNode):
        raise ValueError(f"{source}: layers[{layer_name}].{section} is not a mapping")
    old = _get(mapping, key)
    if old is not None:
        return text[: old.start_mark.index] + value_text + text[old.end_mark.index :]
    return _insert_entry(text, mapping, key, value_text)


def _get(mapping: Any, key: str) -> Any:
    """Value node of ``key`` in a YAML mapping node, or ``None``."""
    import yaml

    if not isinstance(mapping, yaml.MappingNode):
        return None
    for k, v in mapping.value:
        if isinstance(k, yaml.ScalarNode) and k.value == key:
            return v
    return None


def _insert_entry(text: str, mapping: Any, key: str, value_text: str) -> str:
    """Add ``key: value_text`` as the last entry of the mapping node ``mapping``."""
    if not mapping.value:
        if mapping.flow_style:  # "{}"
            at = text.index("}", mapping.start_mark.index)
            return text[:at] + f"{key}: {value_text}" + text[at:]
        raise ValueError("cannot add to an empty block mapping")
    last = mapping.value[-1][1]
    if mapping.flow_style:
        at = last.end_mark.index
        return text[:at] + f", {key}: {value_text}" + text[at:]
    indent = mapping.value[0][0].start_mark.column
    end = last.end_mark
    if end.column == 0:  # a nested block ends at the start of the next line
        at = end.index
    else:
        newline = text.find("\n", end.index)
        at = len(text) if newline < 0 else newline + 1
        if newline < 0:
            text += "\n"
            at += 1
    return text[:at] + " " * indent + f"{key}: {value_text}\n" + text[at:]
