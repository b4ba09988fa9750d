"""The flat plate the rendering tests put before their cameras (one definition, every part a
parameter), and ``same_result``: two renders' bytes and truth equal. Each test file passes its
own plate, cameras and options (the defaults are tests/test_render.py's: one camera of
160×120 px, fx = 2000 px, 300 mm from a 20×15 mm plate that moves by SHIFT at step 1)."""
from __future__ import annotations

import dataclasses

import numpy as np

from glsim.scene import Plate, Render, Scene, Specimen
from glsim.scene.camera import Camera, Distortion
from glsim.scene.tables import as_tuple

SHIFT = (0.37, -0.21, 0.0)  # mm, in the plate's plane


def plate_scene(size=(160, 120), fx=2000.0, distortion=Distortion(), z=300.0, R=None, t=None, plate=None,
                specimen_R=None, *, name="c", fy=None, cx=None, cy=None, second=None, specimen_pose=None,
                speckle=None, lighting=None, optics=None, base_dir=".", **render) -> Scene:
    """A plate specimen before camera ``name`` (``size`` (W, H) px, ``fx``; ``fy`` default ``fx``,
    the principal point default the image centre (W − 1)/2, (H − 1)/2; world→camera ``R``, ``t``,
    default the identity) and, with ``second``, a second camera: the first with these fields
    replaced, a ``pose`` (:class:`~glsim.scene.Pose`) placing it relative to the first as a scene
    file's pose table does.

    The plate (default 20×15 mm, 8×6 elements, moved by SHIFT at step 1) lies at ``z`` mm on the
    optical axis, turned by ``specimen_R``; ``specimen_pose`` places it instead, as a pose table.
    ``speckle``, ``lighting``, ``optics``: those sections (default: the scene's defaults);
    ``render``: the :class:`~glsim.scene.Render` options."""
    W, H = size
    cam = Camera(name=name, size=size, fx=fx, fy=fx if fy is None else fy, cx=(W - 1) / 2 if cx is None else cx,
                 cy=(H - 1) / 2 if cy is None else cy, distortion=distortion,
                 R=R if R is not None else ((1, 0, 0), (0, 1, 0), (0, 0, 1)), t=t if t is not None else (0, 0, 0))
    cams = (cam,)
    if second is not None:
        second = dict(second)
        pose = second.pop("pose", None)
        if pose is not None:
            R2, t2 = pose.matrices(cam, camera=True)
            second.update(R=as_tuple(R2), t=as_tuple(t2))
        cams += (dataclasses.replace(cam, **second),)
    plate = plate or Plate(width=20, height=15, nx=8, ny=6, translations=(SHIFT,))
    if specimen_pose is not None:
        Rp, tp = specimen_pose.matrices(None, camera=False)
        spec = Specimen(plate=plate, R=as_tuple(Rp), t=as_tuple(tp))
    elif specimen_R is None:
        spec = Specimen(plate=plate, t=(0.0, 0.0, z))
    else:
        spec = Specimen(plate=plate, R=specimen_R, t=(0.0, 0.0, z))
    sections = {k: v for k, v in (("speckle", speckle), ("lighting", lighting), ("optics", optics)) if v is not None}
    return Scene(cameras=cams, specimen=spec, render=Render(**render), base_dir=base_dir, **sections)


def same_result(a, b) -> None:
    assert a.image.dtype == b.image.dtype and a.image.tobytes() == b.image.tobytes()
    assert (a.truth is None) == (b.truth is None) and a.stages == b.stages
    if a.truth is not None:
        for k in ("element", "xi", "eta", "ref_uv"):
            assert np.array_equal(getattr(a.truth, k), getattr(b.truth, k), equal_nan=True), k
