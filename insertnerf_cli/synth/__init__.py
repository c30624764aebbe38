"""Procedural synthetic scenes, the training data of the pretrained generator (``insertnerf synth``).

Pipeline per scene: compose.py draws a World into a builder.py Builder (shapes from geometry.py /
implicit.py, surroundings and the sky at infinity from enclosures.py, textures from textures.py / drawing.py /
natural.py, lights) -> layouts.py places cameras -> raycast.py flattens the world for embree ->
render.py + shading.py render each view -> capture.py develops it into an 8-bit photo -> scene.py writes a
Blender-format folder. dataset.py runs scenes in parallel with a manifest and resume.
"""
from insertnerf_cli.synth.capture import CaptureOptions
from insertnerf_cli.synth.dataset import (
           GENERATOR_VERSION,
           DatasetRun,
           Manifest,
           SynthOptions,
           build_dataset,
           generate_dataset,
)
from insertnerf_cli.synth.scene import LAYOUTS, SceneSpec, render_scene

__all__ = ["CaptureOptions", "DatasetRun", "GENERATOR_VERSION", "LAYOUTS", "Manifest", "SceneSpec", "SynthOptions",
           "build_dataset", "generate_dataset", "render_scene"]
