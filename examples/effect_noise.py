"""Sensor noise (paper §2.2.3 and beyond): 2 % Gaussian noise and a Poisson–Gaussian sensor on
the bulge, with the noise field shown. Writes effect_noise.tif and effect_noise.png."""
import dataclasses

from _figure import figure

from glsim.io.images import write_image
from glsim.render import Renderer
from glsim.scene import Noise, bulge_scene

scene = bulge_scene(size=(812, 617), steps=1)
for name, noise in (("gaussian", Noise(sigma=2.0)),
                    ("poisson_gaussian", Noise(model="poisson_gaussian", full_well=5000.0, read_noise=10.0))):
    with Renderer(dataclasses.replace(scene, noise=noise)) as r, Renderer(scene) as s:
        a, b = r.render(0, 1), s.render(0, 1)
    delta = a.image - b.image
    print(f"{name}: noise std {delta.std() * 255:.2f} grey levels of 8 bit")
    if name == "gaussian":
        write_image("effect_noise.tif", a.image, 8)
        figure("effect_noise.png", a.image, delta)
