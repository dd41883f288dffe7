"""``eit-skin fit-device``: fit the layer's model to a device's no-load frame.

Reads the no-load frame (``reference``, in the device's conventions as the patch's
``protocol`` names them: layout, complex part, magnitudes) of a frames file and fits the
homogeneous sheet conductance (S) and the contact impedance (ohm*m; per electrode where the
protocol measures on current-carrying electrodes, else one common value; ``--per-electrode``
overrides) on the layer's forward mesh (:func:`eit_skin.fem.device_fit.fit_device`). Prints
the fitted values, the fit residual (rms, relative to the frame's rms, before and after) and
the electrodes with bad contact. The gain (frame units per volt, ``--gain``, default 1: the
frames are volts) cannot be fitted together with the conductance from one homogeneous frame;
the gain the patch's own conductance implies is printed too. ``--fit-input-gain`` also fits
the board's ``device.negative_input_gain`` (its minus input's gain over its plus input's, from
the same no-load frame: a device calibration, never from presses; pair drives only).
A layer with ``depth`` (a tank) is fitted at that depth; ``--fit-depth`` also fits the depth
(:func:`eit_skin.fem.device_fit.fit_depth`: the conductance and contact impedance fitted at
every depth tried, the depth of the smallest residual; none when the 2-D sheet fits best) and
prints the ``depth`` line to put in the layer (with a comment saying where it came from;
``--write`` does not write it).

``--write`` stores ``material.sheet_conductance`` and ``electrodes.contact_impedance`` (a
number, or a list of one per electrode), and with ``--fit-input-gain``
``device.negative_input_gain``, in the patch file, editing only those entries'
text (comments kept), validated with ``load_patch`` before it atomically replaces the file;
the reconstruction matrix is then built on the calibrated model, cached under the new
content hash like any other patch change. Shipped configs are only written when given by path.
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from eit_skin.cli.errors import USER_ERRORS, report_error
from eit_skin.cli.options import add_patch_options, add_write_option, patch_file

#: Significant digits of the stored values.
DIGITS = 4


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_patch_options(parser)
    parser.add_argument(
        "--frames", required=True, type=Path, metavar="IN.npz", help="its 'reference' is fitted"
    )
    parser.add_argument(
        "--gain", type=float, default=1.0, help="frame units per volt (default 1: volts)"
    )
    parser.add_argument(
        "--per-electrode",
        choices=("auto", "yes", "no"),
        default="auto",
        help="one contact impedance per electrode (auto: when the protocol measures on "
        "current-carrying electrodes)",
    )
    parser.add_argument(
        "--fit-input-gain",
        action="store_true",
        help="also fit device.negative_input_gain (the minus input's gain over the plus "
        "input's; pair drives)",
    )
    parser.add_argument(
        "--fit-depth",
        action="store_true",
        help="also fit a tank's depth (m) to the frame (electrodes as high as wide)",
    )
    add_write_option(parser, "the fitted sheet_conductance and contact_impedance")


def run(args: argparse.Namespace) -> int:
    try:
        path = patch_file(args)
        layer_name, fit, depth = fit_layer(path, args)
        for line in fit.lines():
            print(line)
        if args.fit_depth:
            print(
                f"depth: {depth:.{DIGITS}g} m (add to layers[{layer_name}] as 'depth: "
                f"{depth:.{DIGITS}g}  # fitted to the unloaded frame by eit-skin fit-device "
                "--fit-depth')"
                if depth is not None
                else "depth: none (the 2-D sheet fits best)"
            )
        print(f"gain at the patch's conductance: {fit.gain_at(_patch_sigma(path, layer_name)):.4g}")
        if args.write:
            texts = write_calibration(path, layer_name, fit, args.fit_input_gain)
            written = ", ".join(f"{key}: {text}" for key, text in texts.items())
            print(f"wrote {written} to {path} (layer {layer_name})")
        else:
            print("not written (add --write to store it in the patch file)")
    except USER_ERRORS as exc:
        return report_error("fit-device", exc)
    return 0


def _patch_sigma(path: Path, layer_name: str) -> float:
    from eit_skin.patch.loading import load_patch

    return load_patch(path).layer(layer_name).material.sheet_conductance_s


def fit_layer(path: Path, args: argparse.Namespace):
    """``(layer name, DeviceFit, fitted depth m or None)`` of a patch file's layer.

    On a frames file's ``reference``. ``args``: the command's ``layer``, ``frames``,
    ``gain``, ``per_electrode``, ``fit_input_gain`` and ``fit_depth`` (else the depth is
    the layer's).
    """
    from eit_skin.fem.device_fit import fit_depth, fit_device
    from eit_skin.fem.elements import layer_depth
    from eit_skin.fem.mesh import build_mesh
    from eit_skin.io.npz import FramesNpzReader
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import tank_refusal

    patch = load_patch(path)
    layer = patch.layer(args.layer)
    protocol = layer.measured_protocol
    if not args.frames.is_file():
        raise ValueError(f"{args.frames}: no such file")
    reader = FramesNpzReader(args.frames, convert=protocol.select)
    options = {
        "sheet_conductance_s": layer.material.sheet_conductance_s,
        "contact_impedance_ohm_m": layer.contact_impedance_ohm_m,
        "current_a": layer.current_a,
        "gain": args.gain,
        "magnitude": protocol.magnitude,
        "per_electrode": {"auto": None, "yes": True, "no": False}[args.per_electrode],
        "fit_input_gain": args.fit_input_gain,
    }
    mesh = build_mesh(layer)
    if not args.fit_depth:
        depth = layer_depth(layer)
        fit = fit_device(mesh, protocol, reader.reference, depth=depth, **options)
        return layer.name, fit, None if depth is None else depth.depth_m
    refusal = tank_refusal(layer.material, layer.electrodes)
    if refusal is not None:
        raise ValueError(f"{path}: layers[{layer.name}]: --fit-depth needs a tank: {refusal}")
    height = layer.electrodes[0].width_m
    depth, fit = fit_depth(mesh, protocol, reader.reference, height, **options)
    return layer.name, fit, depth


def write_calibration(path: Path, layer_name: str, fit, input_gain: bool = False) -> dict[str, str]:
    """Store the fit in the patch file; ``{entry: text}`` of what was written.

    Conductance and contact impedance, and with ``input_gain`` ``device.negative_input_gain``.

    Only those entries' text changes; the result must load as the same patch apart from
    them (content hashes compared) before it atomically replaces the file.
    """
    from dataclasses import replace

    import numpy as np

    from eit_skin.cli.tune import set_layer_entry
    from eit_skin.patch.loading import load_patch
    from eit_skin.patch.model import PatchError
    from eit_skin.patch.yaml_reader import read_yaml

    before = load_patch(path)
    layer = before.layer(layer_name)
    raw = next(d for d in read_yaml(path, PatchError)["layers"] if d.get("name") == layer_name)
    if "volume_resistivity" in raw.get("material", {}):
        raise ValueError(
            f"{path}: layers[{layer_name}].material gives volume_resistivity + thickness; "
            "replace them by sheet_conductance to store a calibration"
        )
    sigma_text = f"{fit.sheet_conductance_s:.{DIGITS}g}"
    z = np.asarray(fit.contact_impedance_ohm_m)
    z_text = (
        f"[{', '.join(f'{v:.{DIGITS}g}' for v in z)}]"
        if fit.per_electrode
        else f"{z[0]:.{DIGITS}g}"
    )
    text = path.read_text(encoding="utf-8")
    text = set_layer_entry(text, layer_name, "material.sheet_conductance", sigma_text, str(path))
    text = set_layer_entry(text, layer_name, "electrodes.contact_impedance", z_text, str(path))
    texts = {"sheet_conductance": sigma_text, "contact_impedance": z_text}
    device = layer.device
    if input_gain:
        gain_text = f"{fit.negative_input_gain:.{DIGITS}g}"
        entry = "device.negative_input_gain"
        text = set_layer_entry(text, layer_name, entry, gain_text, str(path))
        texts["negative_input_gain"] = gain_text
        options = dict(device.options) | {"negative_input_gain": float(gain_text)}
        device = replace(device, options=tuple(options.items()))
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".yaml", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        after = load_patch(tmp)
        values = tuple(float(v) for v in z_text.strip("[]").split(","))
        expected_layer = replace(
            layer,
            material=replace(layer.material, sheet_conductance_s=float(sigma_text)),
            contact_impedance_ohm_m=values if fit.per_electrode else values[0],
            device=device,
        )
        expected = replace(
            before,
            layers=tuple(
                expected_layer if lay.name == layer_name else lay for lay in before.layers
            ),
        )
        if expected.content_hash != after.content_hash:
            raise ValueError(
                f"{path}: the edit changed more than the calibrated values; not written"
            )
        os.chmod(tmp, path.stat().st_mode & 0o7777)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return texts
