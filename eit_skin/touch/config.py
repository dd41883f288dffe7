"""The touch classifier's settings, each declared once (:func:`~eit_skin.touch.settings.setting`).

Spreads are in units of the spread one fingertip gives at the same place
(:func:`~eit_skin.touch.shapes.single_contact_spread`: "single-finger spreads"), so the rules
do not depend on the patch's size, electrode layout or reconstruction prior. Where each
default comes from, and why each rule exists: docs/classifier.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from eit_skin.touch.contacts import LEARN_FRACTION, SegmentationConfig
from eit_skin.touch.settings import check_settings, setting
from eit_skin.touch.shapes import BLOB_FRACTION, FINGER_RADIUS_M

_FINGER_SPREADS = "single-finger spreads"


@dataclass(frozen=True)
class ClassifierConfig:
    """Thresholds and timing of the touch classifier (every field a declared setting).

    Attributes:
        segmentation: contact thresholds in noise units (:class:`SegmentationConfig`).
    """

    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    # ---------------------------------------------------------------- baseline and noise
    calibration_s: float = setting(
        0.5, "initial no-touch time that gives the baseline and noise maps", "s", above=0
    )
    baseline_tau_s: float = setting(
        5.0, "time constant of the drift-following baseline (no-touch frames only)", "s", above=0
    )
    noise_tau_s: float = setting(
        10.0,
        "time constant of the per-pixel noise map, learnt from no-touch frames after "
        "calibration; 0 keeps the calibration estimate",
        "s",
        at_least=0,
    )
    average_frames: int = setting(
        2,
        "contacts are found in the mean of the latest this many frames (noise down by its "
        "square root, half a frame period of delay per extra frame)",
        "frames",
        at_least=1,
    )
    noise_window: int = setting(
        3,
        "side of the neighbourhood mean in the calibration noise map (each pixel takes the "
        "larger of that mean and its own estimate)",
        "pixels",
        at_least=1,
    )
    noise_floor_fraction: float = setting(
        0.5,
        "the learnt noise map never drops below this fraction of the calibration noise",
        "",
        at_least=0,
    )
    offset_margin: float = setting(
        2.0,
        "pixels this close to the previous frame's contacts stay out of the sheet-wide "
        "offset (removed from every image before segmentation)",
        _FINGER_SPREADS,
        at_least=0,
    )
    offset_deadband: float = setting(
        1.0,
        "only the part of the sheet-wide offset beyond this is removed (a smaller one moves "
        "no pixel across the contact thresholds)",
        "noise sigmas",
        at_least=0,
    )
    # ---------------------------------------------------------------- START gates
    start_frames: int = setting(
        2,
        "consecutive frames with a contact (or a pooled detection) in the same place before START",
        "frames",
        at_least=1,
    )
    detect_kernel: float = setting(
        2.5,
        "standard deviation of the early START detector's Gaussian kernel (about one "
        "fingertip's whole blob); 0: START on segmented contacts only",
        _FINGER_SPREADS,
        at_least=0,
    )
    k_detect: float = setting(
        5.5, "early START threshold of each pooled detector", "its noise sigmas", above=0
    )
    confirm_s: float = setting(
        0.5,
        "a touch the early detector started with no segmented contact by then ends",
        "s",
        above=0,
    )
    learn_fraction: float = setting(
        LEARN_FRACTION,
        "pooled images with a z-score above this fraction of k_detect (a touch building "
        "up) teach neither noise map",
        "",
        above=0,
        at_most=1,
    )
    start_roughness: float = setting(
        0.5,
        "while the sheet flickers, a candidate STARTs only if its raw image changes by "
        "less than this fraction of itself; 0: no check",
        "",
        at_least=0,
    )
    gate_pixels: float = setting(
        8.0, "contact tracking gate (converted to metres)", "pixels", above=0
    )
    track_missed_frames: int = setting(
        2, "frames a contact track may go unseen before it is dropped", "frames", at_least=0
    )
    lookback_frames: int = setting(
        50,
        "frame times and shapes kept while no touch goes on: how far back a START is dated",
        "frames",
        at_least=1,
    )
    # ---------------------------------------------------------------- event assembly
    end_hold_s: float = setting(0.1, "time without contact before END", "s", at_least=0)
    update_period_s: float = setting(
        0.1, "shortest time between UPDATEs of one touch", "s", at_least=0
    )
    count_frames: int = setting(
        3, "frames a contact count must be seen to count", "frames", at_least=1
    )
    strong_fraction: float = setting(
        0.5,
        "frames whose peak is below this fraction of the touch's largest (press and "
        "release ramps) stay out of the shape features",
        "",
        at_least=0,
        below=1,
    )
    travel_fraction: float = setting(
        0.25,
        "frames whose peak is at least this fraction of the touch's largest enter travel "
        "(the whole stroke)",
        "",
        at_least=0,
        below=1,
    )
    closing_window: int = setting(
        5,
        "rolling median over the blob's major axis and centroid path against single noisy frames",
        "frames",
        at_least=1,
    )
    blob_fraction: float = setting(
        BLOB_FRACTION,
        "pixels weigh in the blob moments by how far they exceed this fraction of the "
        "frame's peak (also used for the single-finger spread map)",
        "",
        at_least=0,
        below=1,
    )
    finger_radius_m: float = setting(
        FINGER_RADIUS_M,
        "radius of the fingertip disc whose image defines the single-finger spread",
        "m",
        above=0,
    )
    contact_spread_m: float = setting(
        0.005,
        "spread of one fingertip's image when no per-pixel map is given",
        "m",
        above=0,
        node=False,  # the node always has the map (contact_geometry)
    )
    # ---------------------------------------------------------------- labels
    rub_travel: float = setting(1.15, "centroid travel that makes a rub", _FINGER_SPREADS, above=0)
    pinch_closing: float = setting(
        0.3,
        "relative narrowing of the blob's major axis that makes a pinch",
        "",
        above=0,
        below=1,
    )
    pinch_trend: float = setting(
        3.0,
        "a still touch whose major axis shrinks steadily with this t-statistic (and "
        "pinch_narrowing) is a pinch",
        "standard errors",
        above=0,
    )
    pinch_narrowing: float = setting(
        0.05,
        "least fitted narrowing over the strong frames for the pinch_trend rule",
        _FINGER_SPREADS,
        at_least=0,
    )
    pinch_shape_z: float = setting(
        5.0,
        "a still touch whose raw frames change their pattern steadily with this z-score "
        "is a pinch (needs the pressure layer's raw frames); 0: off",
        "noise sigmas",
        at_least=0,
    )
    grab_spread: float = setting(
        1.35,
        "blob spread (geometric mean of the principal spreads) that makes a grab",
        _FINGER_SPREADS,
        above=0,
    )
    grab_major: float = setting(
        1.45,
        "a still touch whose blob's median major spread reaches this is a grab (fingers "
        "along an arc)",
        _FINGER_SPREADS,
        above=0,
    )
    stretch_ratio_rub: float = setting(
        0.0,
        "stretch per pascal above which a single still contact is a pinch (stretch layer "
        "only); 0: off",
        "1/Pa",
        at_least=0,
    )
    confidence_gain: float = setting(
        2.0,
        "slope g of the confidence 0.5 + 0.5 tanh(g |f - t| / t) of a feature f deciding "
        "against its threshold t",
        "",
        above=0,
    )
    fault_radius: float = setting(
        2.0,
        "events this close to a faulty electrode get fault_confidence times their confidence",
        _FINGER_SPREADS,
        at_least=0,
    )
    fault_confidence: float = setting(
        0.5, "confidence factor near a faulty electrode", "", above=0, at_most=1
    )

    def __post_init__(self) -> None:
        check_settings(self)
