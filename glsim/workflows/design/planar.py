"""2-D rows of a design: a set-up with one speckle pattern prepared on one camera (its noise-free
reference, per-pixel variance, ROI), its quick (Cramér–Rao) row and its engine row (the reference,
the static pair and the deformed step measured by a 2-D engine, with the exact truth at the
engine's subset centres: px, and mm through the camera scale Z/√(fx·fy)). Stereo rows build on
these in :mod:`~glsim.workflows.design.stereo`; :mod:`~glsim.workflows.design.run` orders and caches both.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from glsim.effects import noise as noisemod
from glsim.errors import GlsimError
from glsim.io.fe import specimen_mesh
from glsim.io.truth import mesh_geometry
from glsim.render import Renderer
from glsim.scene import Scene
from glsim.scene.camera import project_camera_frame
from glsim.scene.locate import points_truth
from glsim.workflows.design import quick, strain as strainmod
from glsim.workflows.design.engine import Engine, write_exchange
from glsim.workflows.design.spec import DicSetting

STATIC_STREAM = 0x5EED   # the static pair's second noise field: seed derived from the realisation's


@dataclass(frozen=True)
class Prepared:
    """A set-up with one speckle pattern, ready to measure: its noise-free reference image
    (full scale, float64), per-pixel variance, ROI and what renders and the truth need."""
    scene: Scene
    camera: str
    step: int
    mesh: object
    reference: object
    image: np.ndarray
    variance: np.ndarray
    roi: np.ndarray


def setup_scene(scene: Scene, speckle_seed: int | None) -> Scene:
    return scene if speckle_seed is None else scene.replace(speckle={"seed": int(speckle_seed)})


def static_seed(noise_seed: int) -> int:
    """The second noise seed of a static pair, distinct from any small seed a spec lists."""
    return int(np.random.SeedSequence([noise_seed, STATIC_STREAM]).generate_state(1)[0])


def prepare(scene: Scene, camera: str, step: int, margin: int) -> Prepared:
    """Render the noise-free reference image and the truth masks; ROI = specimen pixels at step 0
    and at ``step``, eroded by ``margin`` px."""
    mesh = specimen_mesh(scene)
    with Renderer(scene.replace(noise=None), mesh=mesh) as r:
        r0 = r.render(camera, 0, truth=True)
        rk = r.render(camera, step, truth=True)
        reference = r.reference
    roi = r0.truth.mask & rk.truth.mask
    if margin:
        roi = ndimage.binary_erosion(roi, iterations=margin)
    if not roi.any():
        raise GlsimError(f"camera {camera}: no pixel sees the specimen at steps 0 and {step} (ROI margin {margin} px)"
                         " — point the camera at the specimen or lower roi_margin")
    cam = scene.camera(camera)
    table = None
    if scene.noise is not None and scene.noise.model == "heteroscedastic":
        table = noisemod.load_variance_table(scene.resolve(scene.noise.variance_file), cam.bit_depth)
    image = np.asarray(r0.image, np.float64)
    return Prepared(scene, camera, step, mesh, reference, image,
                    quick.pixel_variance(image, scene.noise, cam.bit_depth, table), roi)


def truth_px(prep: Prepared, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """Exact truth at subset centres: u, v (px), mm per px there, valid."""
    cam = prep.scene.camera(prep.camera)
    uv = np.stack([x, y], axis=1).astype(np.float64)
    t = points_truth(mesh_geometry(prep.mesh), cam, uv, prep.step)
    moved, ok = project_camera_frame(np.nan_to_num(t.X_deformed), cam)
    d = moved - uv
    valid = t.valid & ok
    scale = t.X_undeformed[:, 2] / math.sqrt(cam.fx * cam.fy)
    return {"truth_u": np.where(valid, d[:, 0], np.nan), "truth_v": np.where(valid, d[:, 1], np.nan),
            "scale": np.where(valid, scale, np.nan), "truth_valid": valid}


def _motion(prep: Prepared, x: np.ndarray, y: np.ndarray):
    """The exact image motion (u, v, valid) px at reference pixels (x, y): the strain's truth field."""
    t = truth_px(prep, x, y)
    return t["truth_u"], t["truth_v"], t["truth_valid"]


def quick_at(prep: Prepared, setting: DicSetting, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """The Cramér–Rao σ at centres (x, y) rounded to pixels; ∞ where the subset leaves the image."""
    c = np.stack([np.rint(x), np.rint(y)], axis=1).astype(np.int64)
    H, W = prep.image.shape
    h = setting.subset_size // 2
    inside = (c[:, 0] >= h + 1) & (c[:, 0] < W - h - 1) & (c[:, 1] >= h + 1) & (c[:, 1] < H - h - 1)
    out = {k: np.full(len(c), np.inf if k.startswith("sigma") else np.nan) for k in ("sigma_u", "sigma_v", "sssig_x", "sssig_y")}
    if inside.any():
        res = quick.crb(prep.image, prep.variance, c[inside], setting.subset_size, setting.shape_function)
        for k in out:
            out[k][inside] = res[k]
    return {f"quick_{k}": v for k, v in out.items()}


def quick_row(prep: Prepared, setting: DicSetting) -> dict[str, np.ndarray]:
    centres = quick.grid_centres(prep.roi, setting.subset_size, setting.subset_step)
    x, y = centres[:, 0].astype(np.float64), centres[:, 1].astype(np.float64)
    return {"x": x, "y": y, **quick_at(prep, setting, x, y), **truth_px(prep, x, y)}


def noisy_images(prep: Prepared, noise_seed: int) -> list[np.ndarray]:
    """[reference, static, deformed] as the camera writes them (quantised), in full scale."""
    cam = prep.scene.camera(prep.camera)
    full = float(2 ** cam.bit_depth - 1)
    images = []
    for seed, step in ((noise_seed, 0), (static_seed(noise_seed), 0), (noise_seed, prep.step)):
        with Renderer(prep.scene.replace(seed=seed), mesh=prep.mesh, reference=prep.reference) as r:
            images.append(np.asarray(r.render(prep.camera, step, quantize=True).image, np.float64) / full)
    return images


def engine_row(prep: Prepared, setting: DicSetting, noise_seed: int, eng: Engine, folder: Path) -> dict:
    ref, static, deformed = noisy_images(prep, noise_seed)
    # how far the initial FFT search looks: the truth's largest shift over the ROI's corners and centre
    ys, xs = np.nonzero(prep.roi)
    probe = truth_px(prep, xs[:: max(1, len(xs) // 200)].astype(float), ys[:: max(1, len(ys) // 200)].astype(float))
    reach = np.nanmax(np.abs(np.concatenate([probe["truth_u"], probe["truth_v"]])), initial=0.0)
    write_exchange(folder / "exchange", ref, [static, deformed], prep.roi, setting.subset_size,
                   setting.subset_step, setting.shape_function, max(16, int(math.ceil(1.5 * reach)) + 4),
                   strain=setting.strain)
    m = eng.measure(folder / "exchange")
    more = {}
    if setting.strain is not None:
        more = strainmod.row_arrays(m, lambda x, y, f: strainmod.truth(lambda a, b: _motion(prep, a, b), x, y, f),
                                    setting.strain_formulation)
    return {**more, "x": m.x, "y": m.y, "static_u": m.u[0], "static_v": m.v[0], "static_valid": m.valid[0],
            "u": m.u[1], "v": m.v[1], "valid": m.valid[1], "cost": m.cost[1], "engine_seconds": np.float64(m.seconds),
            "engine_version": np.str_(m.version), **quick_at(prep, setting, m.x, m.y), **truth_px(prep, m.x, m.y)}
