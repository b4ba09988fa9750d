"""Depth of field (paper §2.2.2): the bulge through an f/1.4 lens focused on the plate's rim,
and what the blur changed. Writes effect_dof.tif and effect_dof.png."""
import dataclasses

from _figure import figure

from glsim.effects.dof import dof_limits, hyperfocal
from glsim.io.images import write_image
from glsim.render import Renderer
from glsim.scene import Optics, bulge_scene

scene = bulge_scene(size=(812, 617), steps=3)
optics = Optics(focal_length=30.0, f_number=1.4, focus_distance=605.0, pixel_pitch=30.0 / scene.cameras[0].fx)
H = hyperfocal(optics.focal_length, optics.f_number, optics.coc_px * optics.pixel_pitch)
print("hyperfocal %.0f mm, depth of field %.1f … %.1f mm" % (H, *dof_limits(optics.focus_distance, H)))
with Renderer(dataclasses.replace(scene, optics=optics)) as r, Renderer(scene) as s:
    a, b = r.render(0, 3), s.render(0, 3)
write_image("effect_dof.tif", a.image, 8)
figure("effect_dof.png", a.image, a.image - b.image)
