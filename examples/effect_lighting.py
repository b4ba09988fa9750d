"""Lighting (paper §2.2.1, Fig. 5): the bulge under the demo's spotlight, and what the light
changed. Writes effect_lighting.tif and effect_lighting.png in the current directory."""
import dataclasses

from _figure import figure

from glsim.io.images import write_image
from glsim.render import Renderer
from glsim.scene import bulge_scene, demo_effects

scene = demo_effects(bulge_scene(size=(812, 617), steps=1))
lit = dataclasses.replace(scene, optics=None, noise=None)
with Renderer(lit) as r, Renderer(dataclasses.replace(lit, lighting=None)) as u:
    a, b = r.render(0, 1), u.render(0, 1)
write_image("effect_lighting.tif", a.image, 8)
print(f"saturated: {a.saturated:.2%} of the pixels")
figure("effect_lighting.png", a.image, a.image - b.image)
