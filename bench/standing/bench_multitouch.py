"""Several touches, repeatability and damage on real hydrogel skins (issue 37 items 3-4).

Data (data/real/, converted by data/real/convert_hydrogel_eit.py from DSHardman/HydrogelEIT):
``hydrogel_multitouch`` (two-probe presses 108 / 75 / 20 mm apart and the 500 single presses of
the same session), ``hydrogel_rect_repeats`` (50 points x 5 repeats, rectangular skin),
``hydrogel_damage`` (no touch, 1.8 h while the skin was damaged), ``hydrogel_ohmc16``; and the
hydrogel patch simulated (single presses and true two-probe presses).

1. Several touches (:mod:`eit_skin.calibration.multi_touch`, trained on single presses only):
   count right and separation error on simulated true two-probe presses by separation, on
   held-out single presses, and on the real two-probe sets, by training-set size.
2. Repeatability floor of each real skin beside the localiser's error on the same skin
   (:mod:`bench.standing.repeatability`): the rectangle's 50 x 5 repeats, hydrogel_ohmc16's
   near-repeats (presses within 2 mm at the same depth).
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
from bench.standing.repeatability import (
    disc_floor,
    floor_table,
    rect_repeats_session,
    rectangle_floor,
)
from eit_skin.calibration.features import relative_change
from eit_skin.calibration.localiser import PressLocaliser, cross_validate
from eit_skin.calibration.online import MIN_CONFIDENCE, OnlineLocaliser
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
    rect = rectangle_floor()
    disc, wider = disc_floor(), disc_floor(near_m=0.003)
    session, point = rect_repeats_session()
    seen = cross_validate(session, load_patch(REAL / "hydrogel_rect16.yaml").layers[0]).xy_error
    change = relative_change(session.frames, session.baselines())
    per_point = np.array([change[point == p].mean(axis=0) for p in range(int(point.max()) + 1)])
    scatter = np.linalg.norm(change - per_point[point], axis=1).mean()
    between = np.linalg.norm(per_point - per_point.mean(axis=0), axis=1).mean()
    lines += [
        "## Repeatability floor (item 4)",
        "",
        "**Definition** (bench/standing/repeatability.py, the same on both skins): the floor is"
        " the median error an unbiased localiser would have given the scatter of the"
        " localiser's own estimate over repeats of one press (each repeat's distance from the"
        " mean of its press's estimates, scaled by sqrt(n / (n - 1)) to a distance from the"
        " true mean). Each skin's floor is compared with the localiser's error on the same"
        " skin, same folds:",
        "",
        *floor_table([disc, wider, rect]),
        "",
        f"- **hydrogel_ohmc16** (the skin of the issue's N = 400 goal): no repeats were"
        f" recorded; {disc.repeats} stand in for them (an upper bound of the true floor: they"
        f" were pressed at different times). Error / floor = {disc.ratio:.2f}x (goal 1.5x);"
        f" {wider.ratio:.2f}x with the {wider.repeats} (more pairs, a little more of the"
        " localiser's bias between them).",
        f"- **hydrogel_rect_repeats** (the 50 x 5 repeats the issue names; another skin): folds"
        f" by point, so a point is never in its own training set and only {rect.n_train}"
        f" presses at 40 distinct points train each fold (no N = 400 exists there). With the"
        f" point's other repeats in training (5-fold over presses) the error is"
        f" {np.median(seen) * 1e3:.1f} mm (median). In the data itself the scatter of a point's"
        f" repeats is {scatter / between:.2f}x the scatter between points (mean distances of"
        " the relative changes): raw press frames, no unloaded frame per press, 2-6 mm deep"
        " presses; most of its error is the bias of interpolating 40 noisy points, not the"
        " localiser's scatter.",
        "- Before the principal-component projection (eit_skin/calibration/kernel_ridge.py)"
        " and with the floor's old definition (distance from the repeats' mean, not scaled):"
        " hydrogel_ohmc16 1.3 mm floor, 2.6 mm error (2.0x); the old definition understated"
        " the floor by sqrt(2) on pairs. Old localiser, new definition: 1.9 mm floor, 2.6 mm"
        " error (1.38x). The rectangle's numbers do not change (leave-one-out keeps all"
        " inputs there).",
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
