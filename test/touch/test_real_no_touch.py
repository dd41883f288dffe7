"""Issue 37, item 5: on the real no-touch frames of every shared real set (data/real/), the
touch classifier reports no event at all.

What each set has untouched (data/real/README.md): `sciospec_adjacent` 20 object-free frames
of a real tank (`reference_frames`); `hydrogel_ohmc16` the frame before each of its 500
robot presses (`ups`: the sheet at rest, one frame per press cycle, drifting as the gel
creeps and its electrode contacts change); the Ottawa and IIRC sets only their one
`reference` frame. Frames are imaged by the reconstruction node's pipeline
(LayerProcessor, as `eit-skin classify` does) with each set's own patch file, and classified
with the raw frames (START filter, shape evidence) as the node does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from eit_skin.cli.main import main
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.processor import LayerProcessor
from eit_skin.touch.classifier import TouchClassifier
from eit_skin.touch.config import ClassifierConfig
from eit_skin.touch.frame_evidence import channel_electrodes
from eit_skin.touch.shapes import raw_patterns, single_contact_spread

DATA = Path(__file__).resolve().parents[2] / "data" / "real"


def events_of(name: str, frames: np.ndarray, rate_hz: float, config: ClassifierConfig) -> list:
    """Every event of ``frames`` ``[T, M]`` of set ``name`` at ``rate_hz`` (after the first 20
    frames, the pipeline's reference, have also been its noise frames)."""
    with np.load(DATA / f"{name}.npz") as data:
        reference = data["reference"]
    layer = load_patch(DATA / f"{name}.yaml").layers[0]
    imager = LayerImager.build(layer, cache_dir=None)
    processor = LayerProcessor(imager)
    processor.set_reference(reference, 0.0, frames[: processor.reference_frames])
    disc, contact = raw_patterns(layer, imager)
    classifier = TouchClassifier(
        imager.grid.x,
        imager.grid.y,
        config,
        contact_spread_m=single_contact_spread(imager),
        electrodes_m=np.array([e.center for e in layer.electrodes]),
        channel_electrodes=channel_electrodes(imager.protocol),
        disc_rel=disc,
        contact_rel=contact,
    )
    events = []
    for k, frame in enumerate(frames):
        images = processor.step(frame, k / rate_hz)
        if images is None:
            continue
        classifier.set_faulty_electrodes(images.faulty_electrodes)
        events += classifier.step(k / rate_hz, images.image, None, images.frame_v)
    assert classifier.calibrated
    return events + classifier.finish()


def test_a_real_tanks_object_free_frames_give_no_event() -> None:
    # 20 frames: at 20 Hz the default 0.5 s calibration takes 11, the other 9 are classified
    with np.load(DATA / "sciospec_adjacent.npz") as data:
        frames = data["reference_frames"]
    assert events_of("sciospec_adjacent", frames, 20.0, ClassifierConfig()) == []


def test_a_real_skins_frames_at_rest_between_500_presses_give_no_event() -> None:
    """One frame per press cycle (2 s; the robot's own cycle is longer), calibrated over
    the first 20 of them: the gel creeps and its contacts change by 2-10 % over the
    recording, 0.4 % from one press to the next, unlike any touch. Before, contacts of a
    few noise sigmas (below the START bar) froze the baseline, the creep grew under them and
    started a 'grab' at frame 245 that never ended."""
    with np.load(DATA / "hydrogel_ohmc16.npz") as data:
        frames = data["ups"]
    config = ClassifierConfig(calibration_s=40.0)
    assert events_of("hydrogel_ohmc16", frames, 0.5, config) == []


@pytest.mark.parametrize("name", ["ottawa_ph1", "ottawa_ph3", "iirc_rotate"])
def test_a_single_reference_frame_is_refused_with_the_reason_not_a_touch(
    name, tmp_path, capsys, monkeypatch
) -> None:
    # the only untouched frame these sets have: repeated, it does not vary, so there is no
    # noise to measure touches against; classify says so and reports nothing
    with np.load(DATA / f"{name}.npz") as data:
        reference = data["reference"]
    monkeypatch.setenv("EIT_SKIN_CACHE", str(tmp_path / "cache"))
    path = tmp_path / "rest.npz"
    np.savez(path, reference=reference, frames=np.repeat(reference[None], 40, axis=0))
    patch = str(DATA / f"{name}.yaml")
    code = main(["classify", "--patch", patch, "--frames", str(path), "--rate", "20"])
    out, err = capsys.readouterr()
    assert code == 1 and out == ""
    assert "zero noise" in err
