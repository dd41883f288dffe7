"""PNG figures of a design: the predicted-accuracy maps of ``eit-skin patch --predict``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: (map name, title, unit factor, colour map) of each panel.
PANELS = (
    ("position_error_m", "position error [mm]", 1e3, "magma_r"),
    ("resolution", "resolution (GREIT)", 1.0, "viridis_r"),
    ("amplitude_response", "amplitude response", 1.0, "coolwarm"),
)


def draw_accuracy(patch: Any, maps: Sequence[Any], out: Path) -> None:
    """One row per layer: position error, resolution and amplitude response over the sheet.

    With the outline, holes, electrodes and the simulated targets' centres.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        len(maps), len(PANELS), figsize=(5.2 * len(PANELS), 5.0 * len(maps)), squeeze=False
    )
    for row, prediction in zip(axes, maps, strict=True):
        layer = prediction.layer
        extent = (
            prediction.x[0] * 1e3,
            prediction.x[-1] * 1e3,
            prediction.y[0] * 1e3,
            prediction.y[-1] * 1e3,
        )
        for ax, (name, title, factor, cmap) in zip(row, PANELS, strict=True):
            image = prediction.maps[name] * factor
            shown = ax.imshow(image, origin="lower", extent=extent, cmap=cmap)
            fig.colorbar(shown, ax=ax, shrink=0.8)
            closed = np.vstack([layer.outline, layer.outline[:1]]) * 1e3
            ax.plot(closed[:, 0], closed[:, 1], color="k", lw=1.0)
            for hole in layer.holes:
                h = np.vstack([hole, hole[:1]]) * 1e3
                ax.plot(h[:, 0], h[:, 1], color="k", lw=0.8)
            centres = np.array([e.center for e in layer.electrodes]) * 1e3
            ax.plot(centres[:, 0], centres[:, 1], "s", color="tab:green", ms=5)
            ax.plot(
                prediction.centres[:, 0] * 1e3, prediction.centres[:, 1] * 1e3, ".", color="0.5"
            )
            ax.set_aspect("equal")
            ax.set_title(f"{patch.name} / {layer.name}: {title}", fontsize=10)
            ax.set_xlabel("x [mm]")
        row[0].set_ylabel("y [mm]")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)
