"""One design being edited: patch data in, validated model and predicted accuracy out, saved.

The browser sends the whole patch data (what the YAML file parses into) after every change;
:meth:`DesignSession.update` validates it with the patch loader (errors come back as the
loader's message), builds the chosen layer's mesh and its predicted-accuracy preview
(:func:`~eit_skin.pipeline.accuracy_map.predict_accuracy`, ``quality="preview"``) and times
both. :meth:`DesignSession.save` writes the patch file: over the file the design was loaded
from, only the changed values are replaced and the user's comments kept
(:func:`~eit_skin.patch.yaml_writer.updated_text`); the written file is loaded back and must
give the same content hash as the design.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any

import numpy as np

from eit_skin.fem.mesh import build_mesh
from eit_skin.patch.loading import load_patch, patch_from_dict
from eit_skin.patch.model import Patch, PatchError
from eit_skin.patch.yaml_reader import read_yaml
from eit_skin.patch.yaml_writer import new_text, updated_text
from eit_skin.pipeline.accuracy_map import predict_accuracy
from eit_skin.resources import config_path

#: Drawings the designer opens (through :mod:`eit_skin.patch.cad_import`).
DRAWING_SUFFIXES = (".dxf", ".svg")
#: Electrodes spread on a drawing without electrode marks.
DEFAULT_ELECTRODES = 16


class DesignSession:
    """The design being edited.

    Attributes:
        data: the patch data (plain dicts and lists, as parsed from YAML).
        path: the patch file it was loaded from or last saved to (``None``: new).
        original: that file's text (the comments to keep), or ``None``.
    """

    def __init__(self, data: dict[str, Any], path: Path | None, original: str | None) -> None:
        self.data = data
        self.path = path
        self.original = original

    @classmethod
    def open(cls, source: str | Path, units: str | None = None) -> DesignSession:
        """A patch file, a shipped patch's name, or a DXF / SVG drawing.

        A drawing is imported with 16 electrodes spread evenly unless it marks them.
        """
        from eit_skin.patch.cad_import import read_drawing
        from eit_skin.patch.cad_patch import patch_data

        path = Path(source)
        if path.suffix.lower() in DRAWING_SUFFIXES:
            drawing = read_drawing(path, units)
            count = None if drawing.electrode_marks.shape[0] else DEFAULT_ELECTRODES
            return cls(patch_data(drawing, path.stem, count), None, None)
        resolved = config_path(str(source))
        return cls(read_yaml(resolved, PatchError), Path(resolved), resolved.read_text("utf-8"))

    def validate(self, data: dict[str, Any]) -> Patch:
        """The patch of ``data`` (raises :class:`PatchError` naming the key)."""
        return patch_from_dict(copy.deepcopy(data), source=str(self.path or "<design>"))

    def update(self, data: dict[str, Any], layer_index: int = 0) -> dict[str, Any]:
        """Validate and model ``data``; make it the design and describe layer ``layer_index``.

        The answer: outline, holes, electrodes, mesh, predicted-accuracy preview and how long
        the model took; ``{"ok": False, "error"}`` when the data does not validate.
        """
        started = time.perf_counter()
        try:
            patch = self.validate(data)
        except (PatchError, ValueError) as exc:
            return {"ok": False, "error": str(exc)}
        index = min(max(int(layer_index), 0), len(patch.layers) - 1)
        layer = patch.layers[index]
        try:
            mesh = build_mesh(layer)
            meshed = time.perf_counter()
            prediction = predict_accuracy(layer, quality="preview", cache_dir=None)
        except ValueError as exc:
            return {"ok": False, "error": f"layers[{index}]: {exc}"}
        done = time.perf_counter()
        self.data = copy.deepcopy(data)
        perimeter = layer.perimeter_m
        electrodes = [
            {
                "fraction": round(e.center_m / perimeter, 6),
                "center": [float(v) for v in e.center],
                "chain": (mesh.nodes[np.append(ed[:, 0], ed[-1, 1])]).round(7).tolist(),
            }
            for e, ed in zip(layer.electrodes, mesh.electrode_edges, strict=True)
        ]
        answer = prediction.to_json()
        return {
            "ok": True,
            "content_hash": patch.content_hash,
            "layer_names": [lay.name for lay in patch.layers],
            "layer_index": index,
            "outline": layer.outline.round(7).tolist(),
            "holes": [h.round(7).tolist() for h in layer.holes],
            "perimeter_m": perimeter,
            "electrodes": electrodes,
            "mesh": {
                "nodes": mesh.nodes.round(7).tolist(),
                "triangles": mesh.triangles.tolist(),
                "n_triangles": mesh.n_triangles,
            },
            "prediction": {
                "x_m": answer["x_m"],
                "y_m": answer["y_m"],
                "maps": answer["maps"],
                "summary": answer["summary"],
                "line": prediction.line(),
                "targets": answer["phantoms"]["count"],
            },
            "timings_s": {"mesh": meshed - started, **prediction.timings_s, "all": done - started},
        }

    def save(self, path: str | Path | None = None) -> dict[str, Any]:
        """Write the design to ``path`` (default: where it came from); reload and compare.

        Returns ``{"path", "content_hash"}``. Raises :class:`PatchError` when the data does
        not validate or the written file reloads to another content hash.
        """
        target = Path(path) if path else self.path
        if target is None:
            raise PatchError("<design>", "(file)", "no file to save to: give a path")
        patch = self.validate(self.data)
        if self.original is not None:
            text = updated_text(self.original, self.data)
        else:
            text = new_text(self.data)
        target.write_text(text, encoding="utf-8")
        saved = load_patch(target)
        if saved.content_hash != patch.content_hash:
            raise PatchError(str(target), "(file)", "saved file reloads to another content hash")
        self.path, self.original = target, text
        return {"path": str(target), "content_hash": saved.content_hash}
