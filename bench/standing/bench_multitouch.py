"""Several touches, repeatability and damage on real hydrogel skins (issue 37 items 3-4).

Data (data/real/, converted by data/real/convert_hydrogel_eit.py from DSHardman/HydrogelEIT):
``hydrogel_multitouch`` (two-probe presses 108 / 75 / 20 mm apart and the 500 single presses of
the same session), ``hydrogel_rect_repeats`` (50 points x 5 repeats, rectangular skin),
``hydrogel_damage`` (no touch, 1.8 h while the skin was damaged), ``hydrogel_ohmc16``; and the
hydrogel patch simulated (single presses and true two-probe presses).

1. Several touches (:mod:`eit_skin.calibration.multi_touch`, trained on single presses only):
   count right and separation error on simulated true two-probe presses by separation, on
   held-out single presses, and on the real two-probe sets, by training-set size.
2. Repeatability floor (rectangle repeats): the spread of the localiser's out-of-fold estimate
   over the 5 repeats of one point, beside its error; on hydrogel_ohmc16 (no repeats) the
   same spread over near-repeats (presses within 2 mm at the same depth).
3. Damage: the recording through the processor and the calibrated contacts (frames with a
   contact before / after the changed-sheet rule).

Writes bench/multitouch.md.
Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python -m bench.standing.bench_multitouch``.
"""

from __future__ import annotations

import platform
import time
from pathlib import Path

import numpy as np

from bench.standing.real_sessions import load_real, multitouch_single_presses
from eit_skin.calibration.localiser import PressLocaliser, cross_validate
from eit_skin.calibration.online import MIN_CONFIDENCE, OnlineLocaliser
from eit_skin.calibration.session import PressSession
from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.processor import LayerProcessor
from eit_skin.sim.multi_press import simulate_simultaneous_presses
from eit_skin.sim.press_session import simulate_press_session

REPO = Path(__file__).resolve().parents[2]
REAL = REPO / "data" / "real"
OUT = Path(__file__).resolve().parent
SIZES = (100, 200, 400)


def mm(x: float) -> str:
    return f"{x * 1e3:.1f}"


def count_and_separation(model: PressLocaliser, downs, ups) -> tuple[np.ndarray, np.ndarray]:
    counts, seps = [], []
    for f, b in zip(downs, ups, strict=True):
        p = model.locate_touches(np.asarray(f, float), np.asarray(b, float), 2)
        counts.append(len(p.xy))
        seps.append(np.linalg.norm(p.xy[0] - p.xy[1]) if len(p.xy) == 2 else np.nan)
    return np.array(counts), np.array(seps)


def simulated_section(lines: list[str]) -> None:
    patch = load_patch(REAL / "hydrogel_ohmc16.yaml")
    layer = patch.layers[0]
    session = simulate_press_session(patch, 300, seed=11)
    rng = np.random.default_rng(12)
    n = 60
    separation = rng.uniform(0.010, 0.110, n)
    angle = rng.uniform(0.0, 2.0 * np.pi, n)
    centre = rng.uniform(-0.015, 0.015, (n, 2))
    half = np.stack([np.cos(angle), np.sin(angle)], axis=1) * separation[:, None] / 2.0
    points = np.stack([centre + half, centre - half], axis=1)
    frames, baselines = simulate_simultaneous_presses(patch, points, seed=13)
    lines += [
        "## Simulated hydrogel patch: true two-probe presses",
        "",
        f"{n} presses with two 5 N probes at random separations 10-110 mm (simulator physics,"
        " drift, ADC noise); calibrated on N single presses; 100 held-out single presses."
        " Count right = counted two for separations >= the electrode pitch"
        " (33 mm; closer pairs are one touch by design, so for them counted one is right).",
        "",
        "| N | count right, >= 33 mm | count right, < 33 mm (one) | separation error median / p90"
        " (mm) | held-out singles counted two | fit time |",
        "|---|---|---|---|---|---|",
    ]
    far = separation >= 0.033
    for size in (100, 200):
        t0 = time.perf_counter()
        model = PressLocaliser.fit(session.subset(np.arange(size)), layer, 2)
        fit_s = time.perf_counter() - t0
        counts, seps = count_and_separation(model, frames, baselines)
        err = np.abs(seps - separation)[far & (counts == 2)]
        singles, _ = count_and_separation(model, session.frames[200:], session.references[200:])
        lines.append(
            f"| {size} | {int((counts[far] == 2).sum())} / {int(far.sum())} |"
            f" {int((counts[~far] == 1).sum())} / {int((~far).sum())} |"
            f" {mm(np.median(err))} / {mm(np.percentile(err, 90))} |"
            f" {int((singles == 2).sum())} / 100 | {fit_s:.1f} s |"
        )
    # K = 3: three probes on a 35-50 mm circle (60-87 mm apart), same N = 200 calibration
    start, radius = rng.uniform(0.0, 2.0 * np.pi, 20), rng.uniform(0.035, 0.05, 20)
    angle = start[:, None] + np.arange(3)[None, :] * 2.0 * np.pi / 3.0
    triples = np.stack([np.cos(angle), np.sin(angle)], axis=2) * radius[:, None, None]
    frames3, baselines3 = simulate_simultaneous_presses(patch, triples, seed=14)
    counts, misses = [], []
    for k in range(len(triples)):
        touches = model.locate_touches(frames3[k], baselines3[k], 3)
        counts.append(len(touches.xy))
        gaps = np.linalg.norm(touches.xy[:, None, :] - triples[k][None], axis=2)
        misses += gaps.min(axis=1).tolist()
    counts = np.array(counts)
    lines += [
        "",
        f"K = 3, N = 200: 20 presses with three probes 60-87 mm apart: counted three in"
        f" {int((counts == 3).sum())}, two in {int((counts == 2).sum())}; each reported touch"
        f" {mm(np.median(misses))} mm (median; p90 {mm(np.percentile(misses, 90))}) from the"
        " nearest probe.",
        "",
    ]


def real_multitouch_section(lines: list[str]) -> None:
    d = load_real("hydrogel_multitouch")
    layer = load_patch(REAL / "hydrogel_ohmc16.yaml").layers[0]
    singles = multitouch_single_presses(d)
    lines += [
        "## Real hydrogel skin: two probes at once (HydrogelEIT MultiTouch)",
        "",
        "Calibrated on the first N of the session's 500 single robot presses (positions known);"
        " the two-probe presses have no recorded positions, only the probe separation (108, 75,"
        " 20 mm), so separation error is what can be scored. In sets A and B rows 4-7 are"
        " byte-identical copies of rows 0-3 in the source (4 distinct presses each); set C has"
        " 10 distinct presses. Held-out singles: the presses after the first 400.",
        "",
        "| N | A 108 mm: counted two | A: separation (mm) | B 75 mm: counted two |"
        " B: separation (mm) | C 20 mm: counted two | C: separation (mm) |"
        " held-out singles counted two |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for size in SIZES:
        model = PressLocaliser.fit(singles.subset(np.arange(size)), layer, 2)
        counts, seps = count_and_separation(model, d["downs"], d["ups"])
        cells = []
        for name in "ABC":
            rows = d["set"] == name
            cells.append(f"{int((counts[rows] == 2).sum())} / {int(rows.sum())}")
            distinct = rows & (d["duplicate_of"] < 0)
            cells.append(
                ", ".join("-" if np.isnan(s) else f"{s * 1e3:.0f}" for s in seps[distinct])
            )
        held, _ = count_and_separation(model, singles.frames[400:], singles.references[400:])
        lines.append(f"| {size} | " + " | ".join(cells) + f" | {int((held == 2).sum())} / 100 |")
    model = PressLocaliser.fit(singles.subset(np.arange(400)), layer, 2)
    counts, seps = count_and_separation(model, d["downs"], d["ups"])
    summary = []
    for name in "ABC":
        rows = (d["set"] == name) & (counts == 2)
        err = np.abs(seps[rows] - d["separation_m"][rows])
        summary.append(
            f"{name}: median |error| {mm(np.median(err)) if err.size else '-'} mm"
            f" over {int(rows.sum())} counted two"
        )
    frames, refs = singles.frames[400:450], singles.references[400:450]
    cost = {}
    for k in (1, 2):
        t0 = time.perf_counter()
        for f, r in zip(frames, refs, strict=True):
            model.locate_touches(f, r, k)
        cost[k] = (time.perf_counter() - t0) / len(frames)
    lines += [
        "",
        f"Separation error at N = 400: {'; '.join(summary)}.",
        "",
        f"Cost per touched frame at N = 400: {cost[2] * 1e3:.1f} ms with K = 2 (all N^2 pairs"
        f" of calibration presses), {cost[1] * 1e3:.2f} ms with K = 1 (today's localiser).",
        "",
    ]


def floor_section(lines: list[str]) -> None:
    rect = load_real("hydrogel_rect_repeats")
    layer = load_patch(REAL / "hydrogel_rect16.yaml").layers[0]
    point, repeat = rect["point"], rect["repeat"]
    frames = rect["frames"].astype(float)
    # no unloaded frames were recorded: each round of 50 presses is compared with its own
    # median frame (slow drift between rounds cancels)
    rounds = np.array([np.median(frames[repeat == r], axis=0) for r in range(5)])[repeat]
    session = PressSession(rect["reference"], frames, rect["truth_xy"][:, 0], rect["depth"], rounds)
    folds = np.array_split(np.random.default_rng(0).permutation(50), 5)
    xy = np.zeros((len(frames), 2))
    for fold in folds:  # a point's 5 repeats are never in its own training set
        test = np.isin(point, fold)
        model = PressLocaliser.fit(session.subset(~test), layer)
        xy[test] = model.locate(frames[test], session.reference, rounds[test]).xy
    error = np.linalg.norm(xy - session.press_xy, axis=1)
    mean = np.array([xy[point == p].mean(axis=0) for p in range(50)])
    spread = np.linalg.norm(xy - mean[point], axis=1)
    seen = cross_validate(session, layer).xy_error  # repeats of the point in training
    centre = np.linalg.norm(session.press_xy - session.press_xy.mean(axis=0), axis=1)
    change = (frames - rounds) / np.abs(rounds)
    per_point = np.array([change[point == p].mean(axis=0) for p in range(50)])
    scatter = np.linalg.norm(change - per_point[point], axis=1).mean()
    between = np.linalg.norm(per_point - per_point.mean(axis=0), axis=1).mean()
    lines += [
        "## Repeatability floor (item 4)",
        "",
        "**Definition.** The floor is the spread of the localiser's estimate over repeats of"
        " the same press: for each point, the distance of each repeat's out-of-fold estimate"
        " from the mean of that point's estimates (median over presses). No localiser can be"
        " more repeatable than the data it reads; its error can only approach this spread"
        " (the rest of the error is bias: where the point's estimates sit on average).",
        "",
        "**Rectangle repeats** (130 x 60 mm skin, 50 random points x 5 rounds, 2/4/6 mm deep;"
        " folds by point, so a point is never in its own training set):",
        "",
        "| | median | p90 |",
        "|---|---|---|",
        f"| spread over repeats (the floor) | {mm(np.median(spread))} | "
        f"{mm(np.percentile(spread, 90))} |",
        f"| localiser error, point unseen | {mm(np.median(error))} | "
        f"{mm(np.percentile(error, 90))} |",
        f"| localiser error, other repeats of the point in training (5-fold over presses) |"
        f" {mm(np.median(seen))} | {mm(np.percentile(seen, 90))} |",
        f"| always the centre | {mm(np.median(centre))} | {mm(np.percentile(centre, 90))} |",
        "",
        f"Error / floor = {np.median(error) / np.median(spread):.1f}x. In the data itself the"
        f" scatter of a point's repeats is {scatter / between:.2f}x the scatter between points"
        " (mean distances of the relative changes): this recording (raw press frames, no"
        " unloaded frame per press, shallow presses) is barely repeatable, so its floor is"
        " high and says little about the circular skin.",
        "",
    ]
    # circular skin: near-repeats among the 500 presses of hydrogel_ohmc16
    h = load_real("hydrogel_ohmc16")
    layer = load_patch(REAL / "hydrogel_ohmc16.yaml").layers[0]
    s = PressSession(
        h["reference"], h["downs"].astype(float), h["truth_xy"][:, 0], h["depth"], h["ups"]
    )
    cv = cross_validate(s, layer, n_train=400)
    gap = np.linalg.norm(s.press_xy[:, None] - s.press_xy[None], axis=2)
    i, j = np.nonzero(np.triu((gap < 0.002) & np.isclose(s.depth[:, None], s.depth[None]), 1))
    residual = (cv.xy - s.press_xy)[i] - (cv.xy - s.press_xy)[j]
    near_spread = np.linalg.norm(residual, axis=1) / 2.0  # each one's distance from the pair mean
    lines += [
        f"**Circular skin (hydrogel_ohmc16, N = 400, 5-fold)**: no repeats were recorded; the"
        f" {len(i)} pairs of presses within 2 mm of each other at the same depth stand in for"
        " them: the spread of their error vectors about the pair's mean error is"
        f" {mm(np.median(near_spread))} mm (median; p90 {mm(np.percentile(near_spread, 90))}),"
        f" the localiser's error {mm(np.median(cv.xy_error))} mm (median): "
        f"{np.median(cv.xy_error) / np.median(near_spread):.1f}x that near-repeat floor"
        " (the issue's goal: within 1.5x). Near-repeats are up to 2 mm apart and were pressed"
        " at different times, so this floor is an upper bound of the true one and the ratio a"
        " lower bound: the localiser (today's, without the physics prior of item 1) is at"
        " least that far above its floor.",
        "",
    ]


def damage_section(lines: list[str]) -> None:
    patch = load_patch(REAL / "hydrogel_ohmc16.yaml")
    layer = patch.layers[0]
    singles = multitouch_single_presses()
    online = OnlineLocaliser(PressLocaliser.fit(singles, layer), patch, "singles")
    processor = LayerProcessor(LayerImager.build(layer))
    d = load_real("hydrogel_damage")
    touched, contacts, changed, faulty = 0, [], None, set()
    for frame, t in zip(d["frames"].astype(float), d["t"], strict=True):
        images = processor.step(frame, float(t))
        if images is None:
            continue
        touched += images.touching
        faulty |= set(images.faulty_electrodes)
        found = online.contacts(frame, None, images, processor)
        if any(c.confidence >= MIN_CONFIDENCE for c in found):
            contacts.append(float(t))
        if changed is None and online.sheet_changed is not None:
            changed = float(t)
    frames = d["frames"].astype(float)
    last = (frames[-1] - frames[0]) / frames[0]
    named = ", ".join(str(e) for e in sorted(faulty)) or "none"
    lines += [
        "## Damage recording (item 4)",
        "",
        f"{len(frames)} frames every 8 s, no touch, while the skin was damaged: by the end the"
        f" frames moved by {np.sqrt(np.mean(last**2)):.2f} RMS relative change, with"
        f" {np.mean(last > 0):.0%} of the channels rising (a sheet-wide change, not a local"
        " press). Through the product's path (layer processor:"
        " reference of the first 20 frames, drift tracking, fault checks; calibrated contacts"
        " from the 500 single presses of the same skin):",
        "",
        f"- the processor calls {touched} of {processor.frames_imaged} imaged frames touched"
        f" (drift tracking frozen); electrodes the fault checks named at some time: {named};",
        f"- calibrated contacts with confidence >= {MIN_CONFIDENCE}: {len(contacts)} frames"
        f" ({contacts[0]:.0f}-{contacts[-1]:.0f} s), then at {changed:.0f} s the sheet is reported"
        " changed (touched without a break for longer than the drift time constant, 60 s) and no"
        " contact follows. Before this rule: 789 frames with a contact over the whole 1.8 h.",
        "- the image-based touch classifier (`eit-skin classify --patch"
        " data/real/hydrogel_ohmc16.yaml --frames data/real/hydrogel_damage.npz`) reports one"
        " `sheet_changed` line at 96 s and no touch (its changed-sheet rule, docs/classifier.md"
        " 4c; test/pipeline/test_hydrogel_damage.py); before it, ONE grab from 32 s to 6648 s.",
        "",
    ]


def main() -> None:
    t0 = time.perf_counter()
    lines = [
        "# Several touches, repeatability and damage on real hydrogel skins (issue 37 items 3-4)",
        "",
        "Generated by `OPENBLAS_NUM_THREADS=1 .venv/bin/python -m "
        "bench.standing.bench_multitouch` on"
        f" {platform.processor() or platform.machine()}, Python {platform.python_version()},"
        f" numpy {np.__version__}. Data: data/real/README.md (DSHardman/HydrogelEIT, CC BY 4.0,"
        " Hardman, Thuruthel, Iida, Materials Today Electronics 4 (2023) 100032).",
        "",
        "Method (eit_skin/calibration/multi_touch.py): every pair of calibration presses is"
        " fitted to the frame's channel-scaled relative change with non-negative weights;"
        " two touches when the best pair at least one electrode pitch apart leaves a residual"
        " below `threshold` x that of the best near fit (one press or two neighbours), the"
        " threshold splitting 5 % of held-out calibration presses. Each touch sits at its"
        " fitted calibration press. Trained from single presses only.",
        "",
    ]
    real_multitouch_section(lines)
    simulated_section(lines)
    floor_section(lines)
    damage_section(lines)
    lines.append(f"Run time {time.perf_counter() - t0:.0f} s.")
    (OUT / "multitouch.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
