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
        0.5, "s", "> 0", "initial no-touch time that gives the baseline and noise maps"
    )
    baseline_tau_s: float = setting(
        5.0, "s", "> 0", "time constant of the drift-following baseline (no-touch frames only)"
    )
    noise_tau_s: float = setting(
        10.0,
        "s",
        ">= 0",
        "time constant of the per-pixel noise map, learnt from no-touch frames after calibration;"
        " 0 keeps the calibration estimate",
    )
    average_frames: int = setting(
        2,
        "frames",
        ">= 1",
        "contacts are found in the mean of the latest this many frames (noise down by its square "
        "root, half a frame period of delay per extra frame)",
    )
    noise_window: int = setting(
        3,
        "pixels",
        ">= 1",
        "side of the neighbourhood mean in the calibration noise map (each pixel takes the larger"
        " of that mean and its own estimate)",
    )
    noise_floor_fraction: float = setting(
        0.5,
        "",
        ">= 0",
        "the learnt noise map never drops below this fraction of the calibration noise",
    )
    offset_margin: float = setting(
        2.0,
        _FINGER_SPREADS,
        ">= 0",
        "pixels this close to the previous frame's contacts stay out of the sheet-wide offset "
        "(removed from every image before segmentation)",
    )
    offset_deadband: float = setting(
        1.0,
        "noise sigmas",
        ">= 0",
        "only the part of the sheet-wide offset beyond this is removed (a smaller one moves no "
        "pixel across the contact thresholds)",
    )
    # ---------------------------------------------------------------- START gates
    start_frames: int = setting(
        2,
        "frames",
        ">= 1",
        "consecutive frames with a contact (or a pooled detection) in the same place before START",
    )
    detect_kernel: float = setting(
        2.5,
        _FINGER_SPREADS,
        ">= 0",
        "standard deviation of the early START detector's Gaussian kernel (about one fingertip's "
        "whole blob); 0: START on segmented contacts only",
    )
    k_detect: float = setting(
        5.5, "its noise sigmas", "> 0", "early START threshold of each pooled detector"
    )
    confirm_s: float = setting(
        0.5, "s", "> 0", "a touch the early detector started with no segmented contact by then ends"
    )
    learn_fraction: float = setting(
        LEARN_FRACTION,
        "",
        "(0, 1]",
        "pooled images with a z-score above this fraction of k_detect (a touch building up) teach"
        " neither noise map",
    )
    start_roughness: float = setting(
        0.5,
        "",
        ">= 0",
        "while the sheet flickers, a candidate STARTs only if its raw image changes by less than "
        "this fraction of itself; 0: no check",
    )
    gate_pixels: float = setting(
        8.0, "pixels", "> 0", "contact tracking gate (converted to metres)"
    )
    track_missed_frames: int = setting(
        2, "frames", ">= 0", "frames a contact track may go unseen before it is dropped"
    )
    lookback_frames: int = setting(
        50,
        "frames",
        ">= 1",
        "frame times and shapes kept while no touch goes on: how far back a START is dated",
    )
    # ---------------------------------------------------------------- event assembly
    end_hold_s: float = setting(0.1, "s", ">= 0", "time without contact before END")
    update_period_s: float = setting(0.1, "s", ">= 0", "shortest time between UPDATEs of one touch")
    sheet_change_taus: float = setting(
        12.0,
        "baseline_tau_s",
        ">= 0",
        "a touch going on without a break for longer than this many baseline time constants is "
        "the sheet changing (damage, drying, an electrode), not a touch: it ends withdrawn "
        "(confidence 0), and once the sheet is still the classifier calibrates again; 0: off",
    )
    count_frames: int = setting(3, "frames", ">= 1", "frames a contact count must be seen to count")
    strong_fraction: float = setting(
        0.5,
        "",
        "[0, 1)",
        "frames whose peak is below this fraction of the touch's largest (press and release "
        "ramps) stay out of the shape features",
    )
    travel_fraction: float = setting(
        0.25,
        "",
        "[0, 1)",
        "frames whose peak is at least this fraction of the touch's largest enter travel (the "
        "whole stroke)",
    )
    closing_window: int = setting(
        5,
        "frames",
        ">= 1",
        "rolling median over the blob's major axis and centroid path against single noisy frames",
    )
    blob_fraction: float = setting(
        BLOB_FRACTION,
        "",
        "[0, 1)",
        "pixels weigh in the blob moments by how far they exceed this fraction of the frame's "
        "peak (also used for the single-finger spread map)",
    )
    finger_radius_m: float = setting(
        FINGER_RADIUS_M,
        "m",
        "> 0",
        "radius of the fingertip disc whose image defines the single-finger spread",
    )
    contact_spread_m: float = setting(
        0.005,
        "m",
        "> 0",
        "spread of one fingertip's image when no per-pixel map is given",
        node=False,
    )
    # ---------------------------------------------------------------- labels
    rub_travel: float = setting(1.15, _FINGER_SPREADS, "> 0", "centroid travel that makes a rub")
    pinch_closing: float = setting(
        0.3, "", "(0, 1)", "relative narrowing of the blob's major axis that makes a pinch"
    )
    pinch_trend: float = setting(
        3.0,
        "standard errors",
        "> 0",
        "a still touch whose major axis shrinks steadily with this t-statistic (and "
        "pinch_narrowing) is a pinch",
    )
    pinch_narrowing: float = setting(
        0.05,
        _FINGER_SPREADS,
        ">= 0",
        "least fitted narrowing over the strong frames for the pinch_trend rule",
    )
    pinch_shape_z: float = setting(
        5.0,
        "noise sigmas",
        ">= 0",
        "a still touch whose raw frames change their pattern steadily with this z-score is a "
        "pinch (needs the pressure layer's raw frames); 0: off",
    )
    grab_spread: float = setting(
        1.35,
        _FINGER_SPREADS,
        "> 0",
        "blob spread (geometric mean of the principal spreads) that makes a grab",
    )
    grab_major: float = setting(
        1.45,
        _FINGER_SPREADS,
        "> 0",
        "a still touch whose blob's median major spread reaches this is a grab (fingers along an "
        "arc)",
    )
    stretch_ratio_rub: float = setting(
        0.0,
        "1/Pa",
        ">= 0",
        "stretch per pascal above which a single still contact is a pinch (stretch layer only); "
        "0: off",
    )
    confidence_gain: float = setting(
        2.0,
        "",
        "> 0",
        "slope g of the confidence 0.5 + 0.5 tanh(g |f - t| / t) of a feature f deciding against "
        "its threshold t",
    )
    fault_radius: float = setting(
        2.0,
        _FINGER_SPREADS,
        ">= 0",
        "events this close to a faulty electrode get fault_confidence times their confidence",
    )
    fault_confidence: float = setting(
        0.5, "", "(0, 1]", "confidence factor near a faulty electrode"
    )

    def __post_init__(self) -> None:
        check_settings(self)
