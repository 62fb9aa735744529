"""Synthetic ground truth: procedural articulated figures and rigged glTF models rendered by a
Kinect-like depth camera (z-buffer, Nguyen et al. 2012 noise, quantisation, flying pixels,
outliers), with ground-truth joints and exact surface correspondences.

Public API::

    from pointrig.synth import FIGURES, make_figure, Camera, NoiseConfig, synthesize
    seq = synthesize("human", n_frames=30, seed=0, camera=Camera.kinect(320),
                     noise=NoiseConfig(seed=1), speed=1.0, walk=0.0)
    seq.write("out/")        # out/frames/frame_0000.ply ..., out/gt.npz
"""

from __future__ import annotations

from .camera import Camera
from .figures import FIGURES, Figure, make_figure
from .noise import NoiseConfig, axial_sigma
from .render import rasterize
from .scene import SynthSequence, load_gt, synthesize

__all__ = [
    "FIGURES",
    "Camera",
    "Figure",
    "NoiseConfig",
    "SynthSequence",
    "axial_sigma",
    "load_gt",
    "make_figure",
    "rasterize",
    "synthesize",
]
