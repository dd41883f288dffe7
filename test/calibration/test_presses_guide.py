"""Calibration by hand (issue 37 item 2): template, guided press detection, end-to-end accuracy.

The simulated session: a person presses the 25 printed targets of the arm patch with a 2 mm
RMS placement error (eit_skin.sim.hand_session), one press too weak (target 4), one target
redone (target 8); ``eit-skin presses guide --frames`` must find, refuse, redo and pair the
presses by itself, and the calibration fitted on its session must locate new presses within
twice the placement error.
"""

from __future__ import annotations

import dataclasses
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from eit_skin.calibration.guide import DetectedPress, GuidedSession, GuideRules
from eit_skin.calibration.localiser import PressLocaliser
from eit_skin.calibration.session import load_press_session
from eit_skin.calibration.template import (
    FINGER_RADIUS_M,
    FINGER_WIDTH_M,
    PT_PER_MM,
    TemplateError,
    pdf_bytes,
    sheet_clearance,
    spread_targets,
    svg_text,
    template_drawing,
)
from eit_skin.cli.main import main
from eit_skin.patch.loading import load_patch
from eit_skin.resources import config_path
from eit_skin.sim.hand_session import HandHabits, simulate_hand_session
from eit_skin.sim.press_session import simulate_press_session

PLACEMENT_RMS_M = 0.002
N_TARGETS = 25
SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture(scope="module")
def arm():
    return load_patch(config_path("arm"))


@pytest.fixture(scope="module")
def targets(arm):
    return spread_targets(arm.layers[0], N_TARGETS)


@pytest.fixture(scope="module")
def guided(arm, targets, tmp_path_factory):
    """The simulated hand session run through ``presses guide --frames``: (hand, out, dir)."""
    hand = simulate_hand_session(
        arm, targets, seed=0, person=HandHabits(placement_rms_m=PLACEMENT_RMS_M)
    )
    folder = tmp_path_factory.mktemp("guide")
    frames = folder / "hand.npz"
    np.savez(frames, reference=hand.reference, frames=hand.frames, t=hand.t)
    answers = folder / "answers.txt"
    answers.write_text("# one reply per accepted press\n" + "\n".join(hand.answers) + "\n")
    out = folder / "session.npz"
    argv = ["presses", "guide", "--patch", "arm", "--frames", str(frames)]
    argv += ["--targets", str(N_TARGETS), "--out", str(out), "--answers", str(answers)]
    return hand, argv, out, folder


@pytest.fixture(scope="module")
def guide_output(guided):
    import contextlib
    import io

    argv = guided[1]
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(argv)
    return code, stdout.getvalue()


# ------------------------------------------------------------------------- template


def test_targets_are_spread_inside_the_sheet_a_finger_from_edges(arm, targets):
    layer = arm.layers[0]
    assert targets.shape == (N_TARGETS, 2)
    assert sheet_clearance(layer, targets).min() >= FINGER_WIDTH_M - 1e-9
    gaps = np.linalg.norm(targets[:, None] - targets[None], axis=2) + np.eye(N_TARGETS)
    assert gaps.min() >= FINGER_RADIUS_M
    # an even cover: no allowed point of the sheet is far from a target
    radius = 0.040 - FINGER_WIDTH_M
    g = np.linspace(-radius, radius, 41)
    grid = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    grid = grid[np.linalg.norm(grid, axis=1) <= radius]
    cover = np.linalg.norm(grid[:, None] - targets[None], axis=2).min(axis=1)
    assert cover.max() < 1.2 * np.median(gaps.min(axis=1))


def test_svg_template_is_true_scale_and_numbered(arm, targets):
    layer = arm.layers[0]
    root = ET.fromstring(svg_text(template_drawing(layer, targets, "arm")))
    width, height = (float(root.get(k).removesuffix("mm")) for k in ("width", "height"))
    assert root.get("viewBox") == f"0 0 {width:.3f} {height:.3f}"  # 1 user unit = 1 mm
    paths = [
        np.array(re.findall(r"(-?[\d.]+) (-?[\d.]+)", p.get("d")), float)
        for p in root.iter(f"{SVG}path")
    ]
    assert np.ptp(paths[0][:, 0]) == pytest.approx(10.0)  # the scale bar
    outline = max(paths, key=lambda p: np.ptp(p[:, 0]))
    assert np.ptp(outline[:, 0]) == pytest.approx(80.0, abs=0.01)  # the 80 mm disc
    texts = {t.text: (float(t.get("x")), float(t.get("y"))) for t in root.iter(f"{SVG}text")}
    assert "10 mm" in texts
    assert {str(k) for k in range(1, N_TARGETS + 1)} <= set(texts)
    assert {f"E{k}" for k in range(16)} <= set(texts)
    # number k sits by target k: same offsets from the outline's centre (y down on paper)
    centre = 0.5 * (outline.min(axis=0) + outline.max(axis=0))
    label = np.array([texts[str(k + 1)] for k in range(N_TARGETS)]) - centre
    expected = np.stack([targets[:, 0], -targets[:, 1]], 1) * 1e3
    assert np.abs(label - expected - [1.2, -1.2]).max() < 0.01


def test_pdf_template_is_one_true_size_page(arm, targets):
    drawing = template_drawing(arm.layers[0], targets, "arm")
    pdf = pdf_bytes(drawing)
    assert pdf.startswith(b"%PDF-1.4") and pdf.rstrip().endswith(b"%%EOF")
    box = re.search(rb"/MediaBox \[0 0 ([\d.]+) ([\d.]+)\]", pdf)
    assert float(box[1]) / PT_PER_MM == pytest.approx(drawing.width_mm, abs=0.01)
    offsets = re.search(rb"xref\n0 (\d+)\n(.*?)trailer", pdf, re.S)
    rows = offsets[2].split(b"\n")[1 : int(offsets[1])]
    for k, row in enumerate(rows, start=1):  # every xref offset points at its object
        at = int(row[:10])
        assert pdf[at:].startswith(f"{k} 0 obj".encode())
    assert b"(25) Tj" in pdf and b"(10 mm) Tj" in pdf


def test_too_many_targets_are_refused_naming_the_layer(arm):
    with pytest.raises(TemplateError, match=r"layer 'pressure': .*fewer --targets"):
        spread_targets(arm.layers[0], 100)
    with pytest.raises(TemplateError, match="no room"):
        spread_targets(arm.layers[0], 5, margin_m=0.05)


# ------------------------------------------------------------------------- judging


def press(xy, hold=1.0, snr=100.0, peak=1e4, together=1) -> DetectedPress:
    m = np.ones(4)
    return DetectedPress(0.0, hold, np.array(xy), snr, peak, m * 2, m, together, "push")


def test_presses_are_refused_with_the_reason_and_redone():
    targets = np.array([[0.0, 0.0], [0.02, 0.0], [0.0, 0.02], [0.02, 0.02], [0.04, 0.0]])
    guide = GuidedSession(targets, GuideRules(max_offset_m=0.01))
    assert guide.judge(press([0.001, 0.0], hold=0.1)).reason.startswith("too short")
    assert guide.judge(press([0.001, 0.0], snr=5.0)).reason.startswith("too weak: change 5.0")
    assert "on two targets: 2 touches at once" in guide.judge(press([0.0, 0.0], together=2)).reason
    assert "nearer target 2" in guide.judge(press([0.018, 0.0])).reason
    assert guide.current == 0 and not guide.accepted  # refused presses leave the target open
    for k in range(3):
        assert guide.judge(press(targets[k] + 0.003)).accepted
    light = guide.judge(press(targets[3], peak=2e3))
    assert "under 0.25 of your typical press" in light.reason
    last = guide.judge(press(targets[3]))
    assert last.accepted and guide.current == 4
    guide.answer(last, "redo")
    assert guide.current == 3 and 3 not in guide.accepted
    with pytest.raises(ValueError, match="want one of ok, redo"):
        guide.answer(last, "yes")
    with pytest.raises(ValueError, match=r"target\(s\) 4, 5 have no accepted press"):
        guide.session()


def test_detector_keeps_the_baseline_and_plateau_of_each_press():
    """Frames: noise 1e-3 on 8 channels, one missing; a 0.1 change held from 1.0 to 2.0 s."""
    from eit_skin.calibration.guide import PressDetector
    from eit_skin.touch.events import TouchEvent

    rng = np.random.default_rng(0)
    t = np.arange(0, 3.0, 0.05)
    shape = np.linspace(1.0, 2.0, 8)
    frames = 1.0 + 1e-3 * rng.standard_normal((len(t), 8))
    frames += 0.1 * shape * ((t >= 1.0) & (t <= 2.0))[:, None]
    frames[:, 5] = np.nan

    def event(state, at):
        return TouchEvent(1, state, "push", 0.9, at, 1.0, 2.0, (0.01, 0.0), 1e-4, 5e3, 1)

    detector = PressDetector(GuideRules())
    found = []
    for k, at in enumerate(t):
        events = [event("start", at)] if np.isclose(at, 1.0) else []
        events += [event("end", at)] if np.isclose(at, 2.05) else []
        found += detector.step(at, frames[k], events)
    (press,) = found
    assert press.hold_s == pytest.approx(1.0) and press.peak_pa == 5e3
    expected = 1.0 + 0.1 * shape
    ok = np.arange(8) != 5
    np.testing.assert_allclose(press.frame[ok], expected[ok], atol=1e-3)
    np.testing.assert_allclose(press.baseline[ok], 1.0, atol=1e-3)
    assert np.isnan(press.frame[5])
    # RMS change over noise: 0.1 * rms(shape) / 1e-3 (the noise of the quiet frames before)
    rms = 0.1 * np.sqrt(np.mean(shape[ok] ** 2)) / 1e-3
    assert press.snr == pytest.approx(rms, rel=0.3)


def test_rules_refuse_negative_values():
    with pytest.raises(ValueError, match="min_snr: must be >= 0"):
        GuideRules(min_snr=-1.0)


# ------------------------------------------------------------------------- simulated session


def test_guide_finds_refuses_and_redoes_the_hand_presses(guided, guide_output, targets):
    hand, _, out, folder = guided
    code, text = guide_output
    assert code == 0, text
    assert (folder / "session.svg").is_file() and (folder / "session.pdf").is_file()
    weak = re.findall(r"refused, too weak: (.*); press target (\d+) again", text)
    # the brush of the finger on target 4 is refused by its image's peak, and nothing else:
    # the classifier's false touches on idle frames are gone (issue 37 item 5: noise maps
    # that know how few frames they have seen)
    assert [(k, "image peak" in why) for why, k in weak] == [("4", True)]
    assert text.count("answer: redo") == 1
    assert "target 8/25" in text.split("answer: redo")[1].splitlines()[1]
    assert len(re.findall(r"accepted \(", text)) == N_TARGETS + 1  # 25 + the redone one
    session = load_press_session(out)
    assert session.n_presses == N_TARGETS
    np.testing.assert_allclose(session.press_xy, targets)
    # each target's frames are of the press made last for it: the press's change is largest
    # where the finger really was (its image position within a few mm of the true press)
    kept = {int(k): hand.press_xy[i] for i, k in enumerate(hand.press_target)}
    true_xy = np.array([kept[k] for k in range(N_TARGETS)])
    assert np.linalg.norm(true_xy - targets, axis=1).max() < 4 * PLACEMENT_RMS_M
    assert session.references is not None and session.references.shape == session.frames.shape


def test_calibration_from_the_guided_session_meets_the_goal(arm, guided, guide_output, capsys):
    _, _, out, folder = guided
    assert guide_output[0] == 0
    model_path = folder / "calibration.npz"
    argv = ["calibrate", "--patch", "arm", "--presses", str(out), "--out", str(model_path)]
    assert main([*argv, "--physics-prior", "0"]) == 0
    assert "25 presses, 5-fold" in capsys.readouterr().out
    layer = arm.layers[0]
    model = PressLocaliser.fit(load_press_session(out), layer)
    one_layer = dataclasses.replace(arm, layers=(layer,))  # simulate only the pressure layer
    test = simulate_press_session(one_layer, 80, layer.name, seed=7)
    test = test.subset(np.flatnonzero(sheet_clearance(layer, test.press_xy) >= FINGER_WIDTH_M))
    located = model.locate(test.frames, test.reference, test.references)
    error = np.linalg.norm(located.xy - test.press_xy, axis=1)
    # the goal: within 2x the finger's placement error (1.9 mm median: press-calibration.md)
    assert np.median(error) <= 2 * PLACEMENT_RMS_M


def test_guide_refusals_write_nothing(guided, tmp_path, capsys):
    _, argv, _, folder = guided
    out = tmp_path / "s.npz"
    base = [*argv[: argv.index("--out")], "--out", str(out)]
    assert (
        main([*base[: base.index("--targets") + 1], "5", *base[base.index("--targets") + 2 :]]) == 2
    )
    assert "calibrate needs at least 10" in capsys.readouterr().err
    assert main([*base, "--template", str(tmp_path / "t.png")]) == 2
    assert "want a .svg or .pdf file name" in capsys.readouterr().err
    bad = tmp_path / "answers.txt"
    bad.write_text("ok\nyes please\n")
    assert main([*base, "--answers", str(bad)]) == 2
    assert f"{bad}: line 2: 'yes please'" in capsys.readouterr().err
    short = tmp_path / "short.npz"
    with np.load(folder / "hand.npz") as data:
        keep = data["t"] < 8.0
        np.savez(short, reference=data["reference"], frames=data["frames"][keep], t=data["t"][keep])
    argv_short = [*base, "--answers", str(folder / "answers.txt")]
    argv_short[argv_short.index("--frames") + 1] = str(short)
    assert main(argv_short) == 2
    assert "have no accepted press" in capsys.readouterr().err
    assert not out.exists()
