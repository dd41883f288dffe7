"""From a patch file to an image to a touch event: the whole skin in one script.

A simulated fingertip presses the shipped ``face`` patch (the simulator stands in for the
skin board); every frame is imaged by the reconstruction node's per-frame pipeline and the
images go to the touch classifier, which prints what ``eit_classifier`` would publish::

    .venv/bin/python examples/patch_to_touch.py
"""

from eit_skin.patch.loading import load_patch
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.processor import LayerProcessor
from eit_skin.resources import config_path
from eit_skin.sim.simulator import SkinSimulator
from eit_skin.touch.classifier import TouchClassifier, classifier_layers
from eit_skin.touch.shapes import contact_geometry


def main() -> list:
    """Print and return the touch events of a simulated push."""
    patch = load_patch(config_path("face"))  # outline, electrodes, material, solver (YAML)
    layer, _ = classifier_layers(patch)  # the layer that measures pressure
    imager = LayerImager.build(layer)  # mesh, forward model, reconstruction (cached)
    processor = LayerProcessor(imager)  # one frame (V) -> one image (Pa)
    spread = contact_geometry(layer).spread_m  # one fingertip's blur at every pixel, m
    classifier = TouchClassifier(imager.grid.x, imager.grid.y, contact_spread_m=spread)
    recording = SkinSimulator(patch, "push", seed=1).run()  # a 5 N push at 1 s
    frames = recording.layers[layer.name].frames  # [T, M] V
    events = []
    for t_s, frame in zip(recording.t.tolist(), frames, strict=True):
        images = processor.step(frame, t_s)
        if images is None:  # the first frames become the no-touch reference
            continue
        events += classifier.step(t_s, images.image, volts=images.frame_v)
    events += classifier.finish()
    for e in events:
        x_mm, y_mm = (1e3 * c for c in e.centroid_m)
        print(f"{e.t_s:5.2f} s  {e.state:6} {e.label:5} at ({x_mm:+5.1f}, {y_mm:+5.1f}) mm")
    return events


if __name__ == "__main__":
    main()
