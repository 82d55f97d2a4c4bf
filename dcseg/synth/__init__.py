"""Synthetic indoor scenes with ground truth, rendered on the CPU with pybullet.

``generate_scene(SynthConfig(...))`` builds a seeded room (textured walls and floor, tables and
pybullet's example meshes), renders an orbit of posed RGB-D views with per-pixel instance ids,
simulates class-agnostic (SAM-like) and class-aware (open-vocabulary-like) 2D masks at a chosen
noise level, and collects perfect ground truth; ``write_scene`` saves it all to a folder.
pybullet is imported only when a scene is generated (``pip install 'dcseg[synth]'``).
"""

from dcseg.synth.catalogue import VOCABULARY
from dcseg.synth.generate import SynthConfig, SynthScene, generate_scene
from dcseg.synth.noise import NOISE_LEVELS, NoiseLevel
from dcseg.synth.scene import SceneInstance
from dcseg.synth.write import write_scene

__all__ = [
    "NOISE_LEVELS",
    "VOCABULARY",
    "NoiseLevel",
    "SceneInstance",
    "SynthConfig",
    "SynthScene",
    "generate_scene",
    "write_scene",
]
