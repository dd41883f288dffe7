"""False-colour rendering of physical images for rviz (rgb8)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Colour of pixels outside the sheet or in holes (NaN), rgb8.
OUTSIDE_RGB = (40, 40, 40)


def _lookup_table(name: str) -> np.ndarray:
    from matplotlib import colormaps

    return (colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3] * 255).round().astype(np.uint8)


@dataclass(frozen=True)
class ColourScale:
    """Linear map ``[low, high]`` -> a 256-entry colour table; NaN -> :data:`OUTSIDE_RGB`.

    Attributes:
        low, high: values at the two ends of the scale, in the image's unit.
        table: ``[256, 3]`` uint8 colours.
    """

    low: float
    high: float
    table: np.ndarray

    @classmethod
    def named(cls, low: float, high: float, colormap: str = "inferno") -> ColourScale:
        if not high > low:
            raise ValueError(f"colour scale needs high > low, got [{low}, {high}]")
        return cls(float(low), float(high), _lookup_table(colormap))

    def to_rgb(self, image: np.ndarray) -> np.ndarray:
        """``[H, W]`` values -> ``[H, W, 3]`` uint8."""
        values = np.asarray(image, dtype=np.float32)
        finite = np.isfinite(values)
        scaled = (np.where(finite, values, self.low) - self.low) / (self.high - self.low)
        index = np.clip(scaled * 255.0 + 0.5, 0, 255).astype(np.uint8)
        rgb = self.table[index]
        rgb[~finite] = OUTSIDE_RGB
        return rgb
