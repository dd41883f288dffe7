"""Sheet materials: background conductance and the map to pressure or stretch.

A reconstruction yields the relative conductivity change ``r = dsigma / sigma0``
per element.  The :class:`Material` of a layer turns ``r`` into the physical
quantity the layer senses:

* ``pressure`` (painted two-layer rubber, conductive knit: pressure lowers the
  resistance): ``sigma = sigma0 * (1 + p / pressure_scale_pa)``, so
  ``p = pressure_scale_pa * r`` in pascals.
  That is the ``piezoresistive`` press ``response`` (the default).
  ``response: thinning`` is a volume conductor instead (a gelatin-glycerol hydrogel, a
  saline-soaked foam): its sheet conductance is ``sigma_v * t``, and a press thins the sheet
  under the probe, so the conductance *falls*:
  ``sigma = sigma0 / (1 + p / pressure_scale_pa)`` (thickness ``t0 / (1 + p / p_s)``: for
  small ``p`` a linear-elastic ``t0 (1 - p / p_s)``, ``p_s`` the sheet's compressive modulus;
  never zero), so ``p = pressure_scale_pa * (1 / (1 + r) - 1)``: ``pressure_scale_pa`` is the
  pressure that halves the conductance.
* ``stretch`` (porous rubber: stretch raises the resistance):
  ``sigma = sigma0 / (1 + gauge_factor * strain)``, so
  ``strain = (1 / (1 + r) - 1) / gauge_factor`` (dimensionless, 0.5 = 50 %).

``sheet_conductance_s`` is the conductance of one square of the sheet in
siemens (``thickness / volume_resistivity``), the 2-D conductivity the forward
model uses.

Physical range. Difference imaging claims a load's conductance change only within
:data:`CONDUCTANCE_RATIO_LIMIT`: ``1/K <= sigma / sigma0 <= K`` (``K = 10``), i.e.
``r`` in :data:`RELATIVE_CHANGE_RANGE` ``= [1/K - 1, K - 1] = [-0.9, 9]``, symmetric in
log-conductance. Beyond it the linearised reconstruction is no measurement of the sheet
(a vanished conductance, or channels that lost their signal: a dead electrode) and the
images are clipped to the ends (:meth:`Material.physical_range`): pressure
``[-0.9, 9] * pressure_scale_pa``, strain ``[(1/K - 1) / g, (K - 1) / g]`` (the map is
decreasing in ``r``). The same ``K`` tells a load from a lost channel in the electrode-fault
check (:mod:`eit_skin.inverse.electrode_faults`): a tenfold conductance change of the whole
sheet scales a channel's voltage by at most ``K`` either way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

QUANTITIES = ("pressure", "stretch")
RESPONSES = ("piezoresistive", "thinning")
"""How a pressure layer's conductance answers a press: rises (piezoresistive) or falls (a
volume conductor that a press thins); module docstring."""
CONDUCTANCE_RATIO_LIMIT = 10.0
"""The largest factor ``K`` by which a load may change the sheet conductance, either way, that
the images claim (module docstring)."""
RELATIVE_CHANGE_RANGE = (1.0 / CONDUCTANCE_RATIO_LIMIT - 1.0, CONDUCTANCE_RATIO_LIMIT - 1.0)
"""``(lowest, highest)`` relative conductivity change ``r`` an image may show: ``(-0.9, 9)``."""
UNITS = {"pressure": "Pa", "stretch": "1"}


@dataclass(frozen=True)
class Material:
    """Electrical and transduction properties of one sheet.

    Attributes:
        quantity: ``"pressure"`` or ``"stretch"``.
        sheet_conductance_s: background sheet conductance, S (siemens per square), > 0.
        pressure_scale_pa: pressure that doubles the conductance, Pa (pressure only).
        gauge_factor: relative resistance change per unit strain (stretch only), > 0.
        response: a press raises (``"piezoresistive"``) or lowers (``"thinning"``) the
            conductance (pressure only; module docstring).
    """

    quantity: str
    sheet_conductance_s: float
    pressure_scale_pa: float | None = None
    gauge_factor: float | None = None
    response: str = "piezoresistive"

    #: Keys added after patches were hashed: left out of the content hash at their default.
    HASH_ONLY_IF_SET: ClassVar[tuple[str, ...]] = ("response",)

    def __post_init__(self) -> None:
        if self.quantity not in QUANTITIES:
            raise ValueError(f"unknown quantity {self.quantity!r}, expected one of {QUANTITIES}")
        if not np.isfinite(self.sheet_conductance_s) or self.sheet_conductance_s <= 0:
            raise ValueError(f"sheet conductance must be > 0 S, got {self.sheet_conductance_s}")
        if self.response not in RESPONSES:
            raise ValueError(f"unknown response {self.response!r}, expected one of {RESPONSES}")
        if self.response != RESPONSES[0] and self.quantity != "pressure":
            raise ValueError(f"response {self.response!r} is for quantity: pressure only")
        if self.quantity == "pressure":
            scale = self.pressure_scale_pa
            if scale is None or not np.isfinite(scale) or scale <= 0:
                raise ValueError(f"pressure_scale must be > 0 Pa for a pressure layer, got {scale}")
        else:
            gain = self.gauge_factor
            if gain is None or not np.isfinite(gain) or gain <= 0:
                raise ValueError(f"gauge_factor must be > 0 for a stretch layer, got {gain}")

    @property
    def unit(self) -> str:
        """SI unit of the physical quantity: ``"Pa"`` or ``"1"`` (strain)."""
        return UNITS[self.quantity]

    @property
    def linear_pascals(self) -> float:
        """Pa per unit relative change of a linear (piezoresistive) pressure layer, else 0."""
        linear = self.quantity == "pressure" and self.response == "piezoresistive"
        return float(self.pressure_scale_pa) if linear else 0.0

    @property
    def physical_range(self) -> tuple[float, float]:
        """``(lowest, highest)`` value of the layer's quantity (Pa or strain) an image may show.

        The images of :data:`RELATIVE_CHANGE_RANGE` (module docstring), in increasing order.
        """
        ends = self.to_physical(np.array(RELATIVE_CHANGE_RANGE))
        return float(ends.min()), float(ends.max())

    def to_physical(self, relative_change: np.ndarray | float) -> np.ndarray:
        """Physical quantity (Pa or strain) from ``r = dsigma/sigma0``; any shape, same shape out.

        For stretch, ``r <= -1`` (conductivity gone) maps to ``+inf`` strain without warnings;
        NaN (no sheet there) stays NaN.
        """
        r = np.asarray(relative_change, dtype=float)
        if self.linear_pascals:
            return self.linear_pascals * r
        gain = self.gauge_factor or 1.0 / self.pressure_scale_pa  # stretch, or thinning
        gone = r <= -1.0
        safe = np.where(gone, 1.0, 1.0 + r)
        return np.where(gone, np.inf, (1.0 / safe - 1.0) / gain)

    def from_physical(self, quantity: np.ndarray | float) -> np.ndarray:
        """Relative conductivity change ``r`` from a pressure (Pa) or strain; same shape out.

        For stretch, ``strain <= -1/gauge_factor`` would need infinite conductivity and
        maps to ``+inf``; NaN stays NaN.
        """
        q = np.asarray(quantity, dtype=float)
        if self.linear_pascals:
            return q / self.linear_pascals
        denominator = 1.0 + (self.gauge_factor or 1.0 / self.pressure_scale_pa) * q
        gone = denominator <= 0
        safe = np.where(gone, 1.0, denominator)
        return np.where(gone, np.inf, 1.0 / safe - 1.0)

    def conductance(self, quantity: np.ndarray | float) -> np.ndarray:
        """Sheet conductance (S) under a pressure (Pa) or strain; same shape out."""
        return self.sheet_conductance_s * (1.0 + self.from_physical(quantity))
