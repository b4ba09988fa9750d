"""What is rendered, free of GL: the scene model (frozen dataclasses), its file loader, the
built-in scenes, and the models it is made of (camera, mesh, Q4 element, speckle)."""
from glsim.scene.load import load_scene, scene_from_dict
from glsim.scene.model import (BACKENDS, INTERPOLATIONS, MODES, Bulge, MeshFile, Output, Plate, Render, Scene,
                               Specimen, Speckle)
from glsim.scene.optional import Exposure, Light, Lighting, Noise, Optics, Psf, Sensor, Vignetting
from glsim.scene.tables import Pose, Stereo
from glsim.scene.presets import bulge_scene, demo_effects, stereo_rig

__all__ = ["BACKENDS", "INTERPOLATIONS", "MODES", "Bulge", "Exposure", "Light", "Lighting", "MeshFile", "Noise", "Optics",
           "Output", "Plate", "Pose", "Psf", "Render", "Scene", "Sensor", "Specimen", "Speckle", "Stereo", "Vignetting",
           "bulge_scene", "demo_effects", "load_scene", "scene_from_dict", "stereo_rig"]
