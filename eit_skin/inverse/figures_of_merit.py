"""GREIT figures of merit of a reconstructed image (Adler et al., Physiol. Meas. 30, 2009).

All measures are computed on a pixel image ``[H, W]`` (NaN outside the sheet) for one
small target of known centre (metres). ``x_q`` is the set of pixels whose value, signed
so that the target's change is positive, is at least a quarter of the maximum.

* amplitude response: integral of the image over the sheet / (contrast * target area);
* position error: distance between the target centre and the centre of gravity of
  ``x_q`` (metres; GREIT's radial variant ``radial_error`` = ``r_target - r_cog``);
* resolution: ``sqrt(area(x_q) / area(sheet))``;
* shape deformation: fraction of ``x_q`` outside the circle ``C`` of equal area
  centred on the centre of gravity;
* ringing: summed opposite-sign image outside ``x_q`` / summed image over ``x_q``
  (EIDORS ``eval_GREIT_fig_merit``: ``-sum(img .* ((img < 0) & ~qmi)) / sum(img .* qmi)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FiguresOfMerit:
    """GREIT measures for one target (lengths in metres, others dimensionless)."""

    amplitude_response: float
    position_error_m: float
    radial_error_m: float
    resolution: float
    shape_deformation: float
    ringing: float
    centre_of_gravity_m: tuple[float, float]


def figures_of_merit(
    image: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    target_centre_m: tuple[float, float],
    sheet_centre_m: tuple[float, float] = (0.0, 0.0),
    target_area_m2: float | None = None,
    contrast: float | None = None,
    sign: float | None = None,
) -> FiguresOfMerit:
    """GREIT figures of merit of ``image`` ``[H, W]`` on pixel centres ``x [W]``, ``y [H]``.

    Args:
        image: relative conductivity change per pixel, NaN outside the sheet.
        x: ``[W]`` pixel-centre x coordinates, metres.
        y: ``[H]`` pixel-centre y coordinates, metres.
        target_centre_m: true target centre, metres.
        sheet_centre_m: centre used for the radial error.
        target_area_m2: true target area, m^2 (for the amplitude response, else NaN).
        contrast: true relative conductivity change of the target (for the amplitude response).
        sign: +1 for a more conductive target, -1 for less; default: sign of the extreme pixel.

    Raises:
        ValueError: the image is empty (all NaN or all zero).
    """
    img = np.asarray(image, dtype=np.float64)
    inside = np.isfinite(img)
    if not inside.any():
        raise ValueError("image has no finite pixel")
    vals = np.where(inside, img, 0.0)
    if sign is None:
        k = np.unravel_index(np.argmax(np.abs(vals)), vals.shape)
        sign = 1.0 if vals[k] >= 0 else -1.0
    s = sign * vals
    peak = float(s.max())
    if not peak > 0:
        raise ValueError("image has no change of the target's sign")
    xx, yy = np.meshgrid(np.asarray(x, float), np.asarray(y, float))
    pixel_area = float(abs(x[1] - x[0]) * abs(y[1] - y[0])) if len(x) > 1 and len(y) > 1 else 1.0
    q = inside & (s >= 0.25 * peak)
    w = s[q]
    cog = (float((w * xx[q]).sum() / w.sum()), float((w * yy[q]).sum() / w.sum()))
    t = np.asarray(target_centre_m, float)
    c0 = np.asarray(sheet_centre_m, float)
    position_error = float(np.hypot(cog[0] - t[0], cog[1] - t[1]))
    radial_error = float(np.linalg.norm(t - c0) - np.linalg.norm(np.asarray(cog) - c0))
    area_q = q.sum() * pixel_area
    resolution = float(np.sqrt(area_q / (inside.sum() * pixel_area)))
    r_c = np.sqrt(area_q / np.pi)
    in_c = inside & ((xx - cog[0]) ** 2 + (yy - cog[1]) ** 2 <= r_c**2)
    shape_deformation = float((q & ~in_c).sum() / q.sum())
    ringing = float(-s[inside & ~q & (s < 0)].sum() / w.sum())
    if target_area_m2 is not None and contrast is not None and contrast != 0:
        amplitude = float(vals.sum() * pixel_area / (contrast * target_area_m2))
    else:
        amplitude = float("nan")
    return FiguresOfMerit(
        amplitude_response=amplitude,
        position_error_m=position_error,
        radial_error_m=radial_error,
        resolution=resolution,
        shape_deformation=shape_deformation,
        ringing=ringing,
        centre_of_gravity_m=cog,
    )
