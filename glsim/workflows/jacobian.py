"""``glsim jacobian SCENE --camera C --step K -o J.npz``: one image's Jacobian with respect to the
nodal displacements (:mod:`glsim.imaging.jacobian`, docs/jacobian.md) written as one ``.npz``.

The file is scipy.sparse's own CSR layout (``scipy.sparse.load_npz`` reads it: ``format``,
``shape``, ``data``, ``indices``, ``indptr``) plus ``image`` (the rendered float32 image, H × W),
``node_labels`` (column 3·i + c is component c of node ``node_labels[i]``), ``camera``, ``step``,
``backend``, ``mode``; with ``rig``, also the camera-parameter Jacobian (pixels × 23, CSR) as
``rig_data``, ``rig_indices``, ``rig_indptr`` and its column names ``rig_columns``. Every input (scene, camera, step, the request's refusals) is checked by
rendering before anything is written; the file appears complete or not at all.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from glsim.errors import GlsimError
from glsim.io.atomic import atomic_path
from glsim.render import Renderer, Result
from glsim.scene import Scene
from glsim.imaging.jacobian import RIG_COLUMNS


def _output(out: str | Path) -> Path:
    out = Path(out)
    if out.suffix != ".npz":
        raise GlsimError(f"-o {out}: the Jacobian is written as a .npz file — give a name ending in .npz, e.g. J.npz")
    if out.is_dir():
        raise GlsimError(f"-o {out}: is a directory — give a file name ending in .npz")
    return out


def camera_arg(text: str) -> int | str:
    """``--camera``: an index (digits) or a name."""
    return int(text) if text.isdigit() else text


def jacobian(scene: Scene, camera: int | str, step: int, out: str | Path, backend: str | None = None,
             rig: bool = False) -> Result:
    """Render ``camera`` at ``step`` with its Jacobian (and, if ``rig``, the camera parameters')
    and write ``out`` (.npz) atomically; returns the Result."""
    path = _output(out)
    with Renderer(scene, backend) as r:
        res = r.render(camera, step, jacobian=True, rig=rig)
        labels = r.mesh.node_labels
    J, G = res.jacobian, res.rig_jacobian
    extra = {} if G is None else {"rig_data": G.data, "rig_indices": G.indices, "rig_indptr": G.indptr,
                                  "rig_columns": np.array(RIG_COLUMNS)}
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        np.savez_compressed(f, format=np.array("csr"), shape=np.array(J.shape), data=J.data, indices=J.indices,
                            indptr=J.indptr, image=res.image, node_labels=labels, camera=np.array(res.camera.name),
                            step=np.array(step), backend=np.array(res.backend), mode=np.array(res.options.mode), **extra)
    return res
