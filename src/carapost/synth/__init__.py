"""Synthetic head-rig takes with exact ground truth.

>>> from carapost.synth import SynthConfig, build_scene, render_frame
>>> scene = build_scene(SynthConfig(frames=2, size=(320, 180)))
>>> render_frame(scene, 0, 0).shape
(180, 320)
"""

from carapost.synth.render import render_frame
from carapost.synth.scene import SynthConfig, SynthScene, build_scene
from carapost.synth.take import SynthCancelled, generate_take, write_truth

__all__ = ["SynthConfig", "SynthScene", "build_scene", "render_frame", "generate_take",
           "write_truth", "SynthCancelled"]
