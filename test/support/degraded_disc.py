"""A degrading electrode's frames and the pipeline's images of them (classifier tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eit_skin.patch.model import Layer
from eit_skin.patch.protocol import Protocol
from eit_skin.pipeline.builder import LayerImager
from eit_skin.pipeline.processor import LayerProcessor


def degrade(frames, protocol: Protocol, electrode: int, when, seed: int) -> np.ndarray:
    """``frames`` ``[T, M]`` V with 10x noise on every channel of ``electrode`` in the frames
    ``when`` ``[T]`` bool (noise measured on the first 25 frames; a copy)."""
    frames = frames.copy()
    sigma = np.std(np.diff(frames[:25], axis=0), axis=0) / np.sqrt(2.0)
    rng = np.random.default_rng(seed)
    chans = protocol.touching([electrode])
    noise = rng.normal(size=frames.shape) * sigma * np.sqrt(10.0**2 - 1)
    frames[np.ix_(when, chans)] += noise[np.ix_(when, chans)]
    return frames


def pipeline_images(layer: Layer, t, frames, cache: Path):
    """``(imager, images [T, H, W], faulty sets per frame)``: ``frames`` imaged by the
    reconstruction node's pipeline, the reference the mean of its first frames."""
    imager = LayerImager.build(layer, cache_dir=cache)
    proc = LayerProcessor(imager)
    n_ref = proc.reference_frames
    proc.set_reference(frames[:n_ref].mean(axis=0), 0.0, frames[:n_ref])
    images, faulty = [], []
    for k in range(len(t)):
        images.append(proc.step(frames[k], float(t[k])).image)
        faulty.append(tuple(proc.faulty_electrodes))
    return imager, np.array(images), faulty
