"""Touch classifier on HARD simulated scenes: light, short, close, back-to-back, drifting, faulty.

For every shipped patch and every category, one scene per seed: the touch categories of
:func:`~eit_skin.sim.random_scenes.hard_scenario` (light central pushes, pushes at an electrode,
slow / fast / short rubs, close pinches in the middle and at the edge, uneven and palm grabs,
back-to-back touches 0.1-0.2 s apart), ``drift_noise`` (random touches, 5x the usual sigma0
drift, 3x the ADC noise), and two no-touch scenes: ``temperature`` (fast sigma0 drift with a
wobble) and ``degrading_electrode`` (10x noise on every channel of one electrode for 5 s).
Frames are imaged by the reconstruction node's per-frame pipeline
(:class:`~eit_skin.pipeline.processor.LayerProcessor`: drift tracking, fault checks), and its
``faulty_electrodes`` go to the classifier every frame, as in ``eit-skin classify``.

Reports per-class recall, confusion, false events per minute of no-touch time (idle scenes,
plus unmatched events of touch scenes over their no-touch time), events lasting longer than
their touch + 0.5 s, and START latency. TUNING seeds were looked at while choosing the
method; REPORT seeds only for the report (``--set report`` writes bench/standing/hard_scenes.md).

MEASURED IN SIMULATION ONLY.

    .venv/bin/python -m bench.standing.bench_hard_scenes [--set report|tuning]
        [--patches arm face elbow]
        [--methods patch greit one_step:laplace ... | all] [--no-learned]

``--methods``: image the same simulated frames with each method (and prior) the patch may
choose (:data:`METHOD_CHOICES`), one table row per patch and method, and every false event
listed with the electrodes the pipeline named faulty around it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bench.header import load_average, run_header
from bench.standing import touch_learned
from bench.standing.touch_scoring import balanced_accuracy, confusion, match, recalls, score
from eit_skin.frames import flagged_as_nan
from eit_skin.inverse.methods import DEFAULT_NOISE_FIGURE
from eit_skin.patch.loading import load_patch
from eit_skin.patch.model import METHODS, METHODS_WITH_PRIOR, PRIOR_KINDS, Patch, SolverSpec
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.processor import LayerProcessor, fault_check_phase
from eit_skin.resources import config_path
from eit_skin.sim.adc import AdcConfig
from eit_skin.sim.drift import DriftModel
from eit_skin.sim.random_scenes import HARD_SCENES, hard_scenario, random_scenario
from eit_skin.sim.scenario import Scenario
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.touch.classifier import TouchClassifier, classifier_layers
from eit_skin.touch.events import LABELS
from eit_skin.touch.frame_evidence import channel_electrodes
from eit_skin.touch.shapes import contact_geometry

RATE_HZ = 50.0
SECONDS = 20.0
IDLE_SCENES = ("temperature", "degrading_electrode")
SCENES = (*HARD_SCENES, "drift_noise", *IDLE_SCENES)
SEEDS = {"tuning": (1,), "report": (101,)}
LATENCY_TARGET_S = 0.100
OVERRUN_S = 0.5
DEGRADE_WINDOW_S = (5.0, 10.0)
DEGRADE_NOISE = 10.0
METHOD_CHOICES = (
    "patch",
    *(
        f"{m}:{p}" if m in METHODS_WITH_PRIOR else m
        for m in METHODS
        for p in (PRIOR_KINDS if m in METHODS_WITH_PRIOR else ("",))
    ),
)
"""``--methods`` values: ``patch`` (the patch's own solver), every method of
:data:`~eit_skin.patch.model.METHODS` with each prior it takes; ``one_step:laplace`` is the
package default (:class:`~eit_skin.patch.model.SolverSpec`)."""
CACHE_VERSION = 5
"""Part of the cached scenes' key: 3 since the pipeline's fault check names noisy electrodes
(the imaged frames and faulty sets of earlier versions are stale); 4 since the raw frames of
the pressure layer are kept too (the classifier's ``shape_z``); 5 since fault checks fall on
the layer's phased grid of frame times, as in the node."""


@dataclass
class Run:
    """Images, raw frames, faulty-electrode sets and truth of one scene."""

    t: np.ndarray
    pressure: np.ndarray
    stretch: np.ndarray | None
    faulty: np.ndarray  # [T, E] bool
    truth: list[dict]
    volts: np.ndarray | None = None  # [T, M] V, the pressure layer's frames (NaN: flagged)


def _key(patch: Patch, *parts) -> str:
    text = json.dumps([[ly.content_hash for ly in patch.layers], CACHE_VERSION, *parts])
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def _simulator(patch: Patch, scene: str, seed: int, seconds: float) -> SkinSimulator:
    drift = None
    adc = None
    if scene in HARD_SCENES:
        scenario = hard_scenario(scene, seed, seconds, patch)
    elif scene == "drift_noise":
        scenario = random_scenario(seed, seconds, patch)
        base = DriftModel.random(seed)
        drift = DriftModel(5 * base.rate_per_min, 5 * base.wobble, 30.0, base.phase)
        adc = AdcConfig(noise_lsb=3.0)
    else:
        scenario = Scenario(scene, (), seconds)
        if scene == "temperature":  # ~5 %/min with a 0.3 % wobble of 15 s
            sign = 1 if seed % 2 else -1
            drift = DriftModel(sign * 0.05, 0.003, 15.0, 0.1 * seed)
    return SkinSimulator(patch, scenario, RATE_HZ, seed=seed, drift=drift, adc=adc)


def with_method(patch: Patch, method: str) -> Patch:
    """``patch`` with every layer imaged by ``method`` (:data:`METHOD_CHOICES`).

    ``"patch"`` keeps the patch's own solver; another name sets ``solver.method`` (and
    ``solver.prior`` after a colon) with the method's default noise figure and no fixed
    hyperparameter, as a user who writes only the method would; the image grid is kept.
    """
    if method == "patch":
        return patch
    name, _, prior = method.partition(":")
    layers = []
    for layer in patch.layers:
        own = layer.solver
        solver = replace(
            own,
            method=name,
            prior=prior or SolverSpec.prior,
            noise_figure=DEFAULT_NOISE_FIGURE[name],
            hyperparameter=None,
        )
        if (
            own.hyperparameter is None
            and (own.noise_figure or DEFAULT_NOISE_FIGURE[own.method]) == (solver.noise_figure)
            and (own.method, own.prior) == (solver.method, solver.prior)
        ):
            solver = own  # the patch's own solver already (elbow: one-step Laplace, NF 0.3)
        layers.append(replace(layer, solver=solver))
    if all(a is b for a, b in zip(patch.layers, layers, strict=True)):
        return patch
    return replace(patch, layers=tuple(layers))


def _simulate_frames(patch: Patch, scene: str, seed: int, seconds: float, data: Path) -> dict:
    """Raw frames of one scene (every classified layer), flags and truth; cached.

    The degrading electrode's extra noise is added here, so every method images the same
    frames. Keys: ``t``, ``frames/<layer>``, ``flags/<layer>``, ``truth`` (JSON).
    """
    path = data / f"{patch.name}-{scene}-{seed}-raw-{_key(patch, scene, seed, seconds)}.npz"
    if path.is_file():
        with np.load(path) as d:
            return {k: d[k] for k in d.files}
    sim = _simulator(patch, scene, seed, seconds)
    rec = sim.run(duration_s=seconds)
    out = {"t": rec.t}
    for layer in classifier_layers(patch):
        if layer is None:
            continue
        lr = rec.layers[layer.name]
        frames = lr.frames.copy()
        if scene == "degrading_electrode":
            protocol = sim.protocol(layer.name)
            quiet = frames[: int(0.5 * RATE_HZ)]
            sigma = np.std(np.diff(quiet, axis=0), axis=0) / np.sqrt(2.0)
            rng = np.random.default_rng([seed, 0xDE6])
            electrode = int(rng.integers(protocol.n_electrodes))
            when = (rec.t >= DEGRADE_WINDOW_S[0]) & (rec.t < DEGRADE_WINDOW_S[1])
            chans = protocol.touching([electrode])
            extra = rng.normal(size=frames.shape) * sigma * np.sqrt(DEGRADE_NOISE**2 - 1)
            frames[np.ix_(when, chans)] += extra[np.ix_(when, chans)]
        out[f"frames/{layer.name}"] = frames
        out[f"flags/{layer.name}"] = lr.flags
    out["truth"] = np.array(
        json.dumps(
            [
                {"label": tr.label, "t_start": tr.t_start_s, "t_end": tr.t_end_s + tr.settle_s}
                for tr in rec.truth
            ]
        )
    )
    data.mkdir(parents=True, exist_ok=True)
    np.savez(path, **out)
    return out


def simulate(
    patch: Patch,
    scene: str,
    seed: int,
    seconds: float,
    data: Path,
    cache: Path,
    method: str = "patch",
) -> Run:
    """One scene, simulated (once for every method), imaged by LayerProcessor; cached."""
    imaged = with_method(patch, method)
    path = data / f"{patch.name}-{scene}-{seed}-{_key(imaged, scene, seed, seconds)}.npz"
    if path.is_file():
        with np.load(path) as d:
            stretch = d["stretch"] if d["stretch"].size else None
            truth = json.loads(str(d["truth"]))
            return Run(d["t"], d["pressure"], stretch, d["faulty"], truth, d["volts"])
    raw = _simulate_frames(patch, scene, seed, seconds, data)
    t = raw["t"]
    pressure_layer, stretch_layer = classifier_layers(imaged)
    out, faulty, volts = {}, None, None
    for layer in (pressure_layer, stretch_layer):
        if layer is None:
            continue
        frames, flags = raw[f"frames/{layer.name}"], raw[f"flags/{layer.name}"]
        imager = LayerImager.build(layer, cache_dir=cache)
        proc = LayerProcessor(imager, fault_check_phase=fault_check_phase(patch.name, layer.name))
        n_ref = proc.reference_frames
        proc.set_reference(frames[:n_ref].mean(axis=0), float(t[0]), frames[:n_ref])
        images = np.full((len(t), *imager.grid.shape), np.nan, dtype=np.float32)
        bad = np.zeros((len(t), layer.n_electrodes), dtype=bool)
        for k in range(len(t)):
            res = proc.step(frames[k], float(t[k]), flags[k])
            if res is not None:
                images[k] = res.image
            bad[k, proc.faulty_electrodes] = True
        out[layer.name] = images
        if layer is pressure_layer:
            faulty = bad
            volts = flagged_as_nan(frames, flags)  # as the nodes hand frames on
    stretch = out[stretch_layer.name] if stretch_layer is not None else None
    truth = json.loads(str(raw["truth"]))
    np.savez(
        path,
        t=t,
        pressure=out[pressure_layer.name],
        stretch=np.zeros(0) if stretch is None else stretch,
        faulty=faulty,
        truth=json.dumps(truth),
        volts=volts,
    )
    return Run(t, out[pressure_layer.name], stretch, faulty, truth, volts)


def classify(
    run: Run,
    x,
    y,
    spread,
    electrodes_m,
    config=None,
    faults: bool = True,
    features=None,
    channels=None,
    disc_rel=None,
    contact_rel=None,
):
    """Every event of one scene; the pipeline's faulty electrodes fed each frame.

    ``features``: a dict that receives each touch's final features (by touch id).
    ``channels``: ``[M, E]`` bool channel-electrode map of the pressure layer; with it the
    scene's raw frames go to the classifier too (``shape_z``); ``disc_rel`` and
    ``contact_rel`` (with ``channels``): a touch STARTs from those frames' filter too.
    """
    clf = TouchClassifier(
        x,
        y,
        config,
        contact_spread_m=spread,
        electrodes_m=electrodes_m,
        channel_electrodes=channels,
        disc_rel=disc_rel if channels is not None else None,
        contact_rel=contact_rel,
    )
    volts = run.volts if channels is not None else None
    events, last = [], None
    for k in range(len(run.t)):
        bad = tuple(np.flatnonzero(run.faulty[k])) if faults else ()
        if bad != last:
            clf.set_faulty_electrodes(bad)
            last = bad
        stretch = None if run.stretch is None else run.stretch[k]
        new = clf.step(
            float(run.t[k]), run.pressure[k], stretch, None if volts is None else volts[k]
        )
        events += new
        _keep_features(new, clf, features)
    new = clf.finish()
    _keep_features(new, clf, features)
    return events + new


def _keep_features(events, clf: TouchClassifier, features) -> None:
    if features is not None:
        for e in events:
            if e.state == "end":
                features[e.touch_id] = clf.last_features


def no_touch_s(run: Run, calibration_s: float) -> float:
    """Time of a scene with no touch going on (after calibration), s."""
    t = run.t
    busy = np.zeros(t.size, dtype=bool)
    for tr in run.truth:
        busy |= (t >= tr["t_start"]) & (t <= tr["t_end"])
    return float(np.count_nonzero(~busy & (t >= t[0] + calibration_s)) / RATE_HZ)


def evaluate(
    patch_name: str,
    seeds,
    seconds: float,
    data: Path,
    cache: Path,
    faults: bool = True,
    detector: str = "frames",
    method: str = "patch",
    faulty_at: dict | None = None,
):
    """Per-scene rows and false events of one patch imaged by ``method`` (:func:`with_method`).

    ``faulty_at``: a dict that receives, per false event ``(scene, touch id)``, the
    electrodes the pipeline named faulty from 1 s before it to its end (text).

    ``detector``: what STARTs a touch before its contacts, ``"frames"`` the pooled image and
    the raw frames' filter (as the node and ``eit-skin classify``), ``"image"`` the pooled
    image alone (the classifier before 2026-11-27).
    """
    patch = load_patch(config_path(patch_name))
    layer, _ = classifier_layers(with_method(patch, method))
    imager = LayerImager.build(layer, cache_dir=cache)
    geometry = contact_geometry(layer, cache)
    spread = geometry.spread_m
    electrodes = np.array([e.center for e in layer.electrodes])
    channels = channel_electrodes(imager.protocol)
    disc = contact = None
    if detector == "frames":
        disc, contact = geometry.disc_rel, geometry.contact_rel
    per_scene, touches = {}, []
    for scene in SCENES:
        rows, false, quiet = [], [], 0.0
        for seed in seeds:
            run = simulate(patch, scene, seed, seconds, data, cache, method)
            feats = {}
            events = classify(
                run,
                imager.grid.x,
                imager.grid.y,
                spread,
                electrodes,
                None,
                faults,
                feats,
                channels,
                disc,
                contact,
            )
            r, f = score(events, run.truth)
            if faulty_at is not None:
                for e in f:
                    when = (run.t >= e.t_start_s - 1.0) & (run.t <= e.t_end_s)
                    named = np.flatnonzero(run.faulty[when].any(axis=0))
                    first = [float(run.t[run.faulty[:, i]][0]) for i in named]
                    faulty_at[(scene, e.touch_id)] = ", ".join(
                        f"e{i} from {t:.2f} s" for i, t in zip(named, first, strict=True)
                    )
            rows += r
            false += f
            quiet += no_touch_s(run, 0.5)
            for tr, e in zip(run.truth, match(events, run.truth), strict=True):
                if e is not None:  # (true label, rules' label, features) of a detected touch
                    touches.append((tr["label"], e.label, feats[e.touch_id]))
        per_scene[scene] = (rows, false, quiet)
    return per_scene, touches


def learned_lines(train: list, test: dict) -> list[str]:
    """Rules against softmax regression trained on ``train`` touches, on ``test`` (per patch)."""
    model = touch_learned.train(
        touch_learned.feature_matrix([f for *_, f in train]), [t for t, *_ in train]
    )
    lines = [
        "| patch | touches | rules: balanced / pinch / grab | learned: balanced / pinch / grab |",
        "|---|---|---|---|",
    ]
    for name, touches in test.items():
        learned = touch_learned.predict(
            model, touch_learned.feature_matrix([f for *_, f in touches])
        )
        cells = []
        for predicted in ([p for _, p, _ in touches], learned):
            cm = confusion([(t, p) for (t, *_), p in zip(touches, predicted, strict=True)])
            rec = recalls(cm)
            cells.append(f"{balanced_accuracy(cm):.3f} / {rec[2]:.2f} / {rec[3]:.2f}")
        lines.append(f"| {name} | {len(touches)} | {cells[0]} | {cells[1]} |")
    return lines


def summarise(name: str, per_scene: dict) -> dict:
    rows = [r for rs, _, _ in per_scene.values() for r in rs]
    cm = confusion(rows)
    rec = recalls(cm)
    false = sum(len(f) for _, f, _ in per_scene.values())
    quiet_min = sum(q for *_, q in per_scene.values()) / 60.0
    lat = np.array([r[2] for r in rows if r[2] is not None]) * 1e3
    over = np.array([r[3] for r in rows if r[3] is not None])
    return {
        "patch": name,
        "touches": len(rows),
        "cm": cm,
        "recall": rec,
        "balanced": float(np.nanmean(rec)),
        "false": false,
        "false_per_min": false / max(quiet_min, 1e-9),
        "lat_median": float(np.median(lat)) if lat.size else float("nan"),
        "lat_max": float(lat.max()) if lat.size else float("nan"),
        "lat_within": float(np.mean(lat <= LATENCY_TARGET_S * 1e3)) if lat.size else float("nan"),
        "overruns": int(np.count_nonzero(over > OVERRUN_S)),
        "missed": int(cm[:, 4].sum()),
    }


def scene_lines(per_scene: dict) -> list[str]:
    lines = []
    for scene, (rows, false, quiet) in per_scene.items():
        pred = [p for _, p, *_ in rows]
        truth = {t for t, *_ in rows}
        ok = sum(1 for t, p, *_ in rows if t == p)
        got = ", ".join(f"{lab} {pred.count(lab)}" for lab in (*LABELS, None) if pred.count(lab))
        lines.append(
            f"| {scene} | {'/'.join(sorted(truth)) or '-'} | {ok}/{len(rows)} | "
            f"{got.replace('None', 'missed') or '-'} | {len(false)} | {quiet:.0f} |"
        )
    return lines


def false_lines(name: str, method: str, per_scene: dict, faulty_at: dict) -> list[str]:
    """One row per false event: where, when, what, and whether a fault was named meanwhile."""
    lines = []
    for scene, (_, false, _) in per_scene.items():
        for e in false:
            named = faulty_at.get((scene, e.touch_id), "")
            lines.append(
                f"| {name} | {method} | {scene} | {e.t_start_s:.2f}-{e.t_end_s:.2f} | {e.label} | "
                f"{e.peak_pa / 1e3:.2f} | {e.n_contacts} | {named or '-'} |"
            )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--patches", nargs="+", default=["arm", "face", "elbow"])
    parser.add_argument("--set", choices=tuple(SEEDS), default="report")
    parser.add_argument("--seconds", type=float, default=SECONDS)
    parser.add_argument("--no-faults", action="store_true", help="do not tell the classifier")
    parser.add_argument(
        "--detector",
        choices=("frames", "image"),
        default="frames",
        help="early START from the pooled image and the raw frames' filter, or the image alone",
    )
    parser.add_argument(
        "--methods",
        nargs="+",
        choices=(*METHOD_CHOICES, "all"),
        default=["patch"],
        help="image the scenes with these methods too (all: every one of them)",
    )
    parser.add_argument(
        "--no-learned",
        dest="learned",
        action="store_false",
        help="skip the learned alternative (it simulates the tuning scenes too)",
    )
    parser.add_argument("--data-dir", type=Path, default=Path("/tmp/eit_skin_hard_scenes"))
    parser.add_argument("--cache-dir", type=Path, default=Path("/tmp/eit_skin_classifier_cache"))
    parser.add_argument(
        "--out", type=Path, default=None, help="report (report set: hard_scenes.md)"
    )
    args = parser.parse_args()
    if args.out is None and args.set == "report":
        args.out = Path(__file__).with_name("hard_scenes.md")
    methods = list(METHOD_CHOICES) if "all" in args.methods else args.methods
    seeds = SEEDS[args.set]
    table = [
        "| patch | method | touches | balanced accuracy | recall push / rub / pinch / grab | "
        "missed | false events / min no-touch | events > touch + 0.5 s | START median / max "
        "(ms) | within 100 ms |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    falses = [
        "| patch | method | scene | event (s) | label | peak (kPa) | contacts | faulty named |",
        "|---|---|---|---|---|---|---|---|",
    ]
    load = load_average()
    details, held_out, train = [], {}, []
    done = {}  # (patch, imaging key) -> scores: a method that is the patch's own is run once
    for method in methods:
        for name in args.patches:
            t0 = time.time()
            imaged = with_method(load_patch(config_path(name)), method)
            key = (name, _key(imaged))
            if key not in done:
                faulty_at: dict = {}
                scores = evaluate(
                    name,
                    seeds,
                    args.seconds,
                    args.data_dir,
                    args.cache_dir,
                    not args.no_faults,
                    args.detector,
                    method,
                    faulty_at,
                )
                done[key] = (*scores, faulty_at)
            per_scene, touches, faulty_at = done[key]
            if method == "patch":
                held_out[name] = touches
            if args.set == "report" and method == "patch" and args.learned:  # tuning trains it
                train += evaluate(
                    name,
                    SEEDS["tuning"],
                    args.seconds,
                    args.data_dir,
                    args.cache_dir,
                    not args.no_faults,
                    args.detector,
                )[1]
            s = summarise(name, per_scene)
            rec = " / ".join(f"{v:.2f}" for v in s["recall"])
            line = (
                f"| {name} | {method} | {s['touches']} | {s['balanced']:.3f} | {rec} | "
                f"{s['missed']} | {s['false_per_min']:.2f} ({s['false']}) | {s['overruns']} | "
                f"{s['lat_median']:.0f} / {s['lat_max']:.0f} | {s['lat_within']:.0%} |"
            )
            print(line, f"({time.time() - t0:.0f} s)", flush=True)
            table.append(line)
            falses += false_lines(name, method, per_scene, faulty_at)
            block = [
                f"### {name}, {method}",
                "",
                "| scene | true labels | correct | predicted | false events | no-touch s |",
                "|---|---|---|---|---|---|",
                *scene_lines(per_scene),
                "",
                "| true \\ predicted | " + " | ".join(LABELS) + " | missed |",
                "|---" * 6 + "|",
                *(
                    f"| {lab} | " + " | ".join(str(v) for v in s["cm"][i]) + " |"
                    for i, lab in enumerate(LABELS)
                ),
                "",
            ]
            print("\n".join(block), flush=True)
            details += block
    print("\n".join(falses), flush=True)
    learned = learned_lines(train, held_out) if train else []
    print("\n".join(learned), flush=True)
    if args.out is None:
        return
    report = [
        "# Touch classifier on hard scenes (simulation only)",
        "",
        f"{run_header(load)} See its docstring for the scenes.",
        f"{args.seconds:g} s per scene, one scene per category and patch, seeds "
        f"{list(seeds)} (tuning seeds {list(SEEDS['tuning'])} were looked at while choosing the",
        "method; these were not). Frames imaged by LayerProcessor (the reconstruction node's",
        "pipeline), its faulty electrodes passed to the classifier every frame. Method `patch`:",
        "the patch's own solver (arm, face: GREIT; elbow: one-step Laplace); the others: every",
        "layer imaged by that method (and prior) at its default noise figure, as a user who",
        "writes only `solver: {method: ...}` gets; `one_step:noser` is the package default",
        "(before issue 35's leave-one-set-out choice: `one_step:laplace`).",
        "",
        "Every figure here is in simulated frame time and does not depend on the machine's load.",
        "",
        *table,
        "",
        "Goals: balanced accuracy >= 0.92, every class >= 0.85, <= 0.3 false events per minute",
        "of no-touch time, no event longer than its touch + 0.5 s, START within 100 ms of",
        "contact. Latency is counted from the first frame of force (onset of the ramp); a",
        "touch's end includes a rub's relaxing trail.",
        "",
        "## False events",
        "",
        *falses,
        "",
        "## Rules or a learned classifier?",
        "",
        "Softmax regression (`bench/standing/touch_learned.py`, numpy only) on the rules' features",
        f"({', '.join(touch_learned.FEATURES)}), trained on the tuning seeds' touches of every",
        "patch, against the rules, on these held-out seeds' touches (the same segmented touches;",
        "only the decision differs). The rules are kept unless the model wins on held-out",
        "scenes.",
        "",
        *learned,
        "",
        *details,
    ]
    args.out.write_text("\n".join(report) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
