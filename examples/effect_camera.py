"""Camera effects beyond the paper (docs/camera.md): the bulge through a diffraction-limited lens
(Airy PSF, f/11, 550 nm, 3.45 µm pixels), with natural cos⁴ vignetting and with fixed-pattern
noise (1 % PRNU, 1 DN DSNU), each image beside its change (blue brighter, red darker, scaled to
its largest change). Writes effect_camera.png, or the path given."""
import dataclasses
import sys

import numpy as np
from _figure import diverging

from glsim.render import Renderer
from glsim.scene import bulge_scene
from glsim.scene import Psf, Sensor, Vignetting

out = sys.argv[1] if len(sys.argv) > 1 else "effect_camera.png"
scene = bulge_scene(size=(406, 308), steps=1)
effects = {"Airy PSF": {"psf": Psf(kind="airy", wavelength_nm=550.0, f_number=11.0, pixel_pitch=3.45e-3)},
           "natural vignetting": {"vignetting": Vignetting(natural=True)},
           "fixed-pattern noise": {"sensor": Sensor(prnu=1.0, dsnu=1.0)}}
with Renderer(scene) as r:
    plain = r.render(0, 1).image
rows = []
for name, tables in effects.items():
    with Renderer(dataclasses.replace(scene, **tables)) as r:
        image = r.render(0, 1).image
    delta = image - plain
    limit = float(np.abs(delta).max()) or 1.0
    grey = np.repeat((np.clip(image, 0, 1) * 255).astype(np.uint8)[..., None], 3, axis=-1)
    gap = np.full((image.shape[0], 8, 3), 255, np.uint8)
    rows += [np.hstack([grey, gap, diverging(delta, limit)]), np.full((8, 2 * image.shape[1] + 8, 3), 255, np.uint8)]
    print(f"{name}: change up to {limit * 255:.1f} grey levels of 8 bit")

import imageio.v3 as iio  # noqa: E402

iio.imwrite(out, np.vstack(rows[:-1]))
print(f"wrote {out}")
