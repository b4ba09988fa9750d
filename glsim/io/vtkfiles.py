"""Truth where users look: ParaView files, written with pyevtk (ImageData, collections) and meshio
(the FE mesh).

- :func:`write_truth_vti`: one image's truth as a VTK ImageData (``.vti``) whose points are the
  pixel centres (x = u, y = v, spacing 1 px, so rows run down as in the image) with the maps as
  point arrays: ``mask`` (uint8), ``element`` (int32, −1 outside), ``xi``, ``eta``, ``ref_u``,
  ``ref_v`` (px), and the vectors ``X_undeformed``, ``X_deformed``, ``displacement`` (mm, camera
  0's frame); floats are NaN outside the mask, as in the ``.npz``.
- :func:`write_mesh_series`: the FE mesh in camera 0's frame, one ``.vtu`` per load step (points
  at the undeformed positions, ``displacement`` as point data, so ParaView's *Warp By Vector*
  shows each step) and a ``.pvd`` collection over the steps (the solver's times where known).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from glsim.io.atomic import atomic_path, atomic_paths
from glsim.scene.camera import Camera, to_camera
from glsim.scene.mesh import Mesh


def _point_data(truth: dict[str, np.ndarray]) -> dict:
    """pyevtk point data: (W, H, 1) arrays in x = u, y = v order; vectors as 3 such arrays."""
    def grid(a):
        return np.ascontiguousarray(np.asarray(a).T[..., None])

    def vector(a):
        return tuple(grid(a[..., i]).astype(np.float64) for i in range(3))
    X0, X1 = truth["X_undeformed"], truth["X_deformed"]
    return {"mask": grid(truth["mask"]).astype(np.uint8), "element": grid(truth["element"]).astype(np.int32),
            "xi": grid(truth["xi"]).astype(np.float64), "eta": grid(truth["eta"]).astype(np.float64),
            "ref_u": grid(truth["ref_uv"][..., 0]).astype(np.float64),
            "ref_v": grid(truth["ref_uv"][..., 1]).astype(np.float64),
            "X_undeformed": vector(X0), "X_deformed": vector(X1), "displacement": vector(X1 - X0)}


def write_vti_file(tmp: Path, truth: dict[str, np.ndarray]) -> None:
    """Write ``truth`` as ImageData to ``tmp``, a path ending in ``.vti`` (pyevtk appends it)."""
    from pyevtk.hl import imageToVTK

    imageToVTK(str(tmp.with_suffix("")), pointData=_point_data(truth))     # writes tmp itself


def write_truth_vti(path: str | Path, truth: dict[str, np.ndarray]) -> Path:
    """One image's truth maps as a ``.vti``, atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        write_vti_file(tmp, truth)
    return path


def write_mesh_series(directory: str | Path, mesh: Mesh, cam: Camera, name: str = "mesh") -> list[Path]:
    """``{name}_{step:04d}.vtu`` per load step and ``{name}.pvd`` in ``directory``, in ``cam``'s
    frame (mm), written atomically as one group (the ``.pvd`` last)."""
    import meshio

    directory = Path(directory)
    X0 = to_camera(mesh.nodes, cam)
    tri = mesh.quads[:, 2] == mesh.quads[:, 3]                 # triangles stored as collapsed quads
    if mesh.is_quadratic:   # the source element types: quad8 (derived centre), quad9, triangle6
        p = mesh.patches
        q8, t6 = p[:, 8] == -1, p[:, 8] == -2                   # glsim.scene.quadratic's centre codes
        blocks = (("quad8", p[q8, :8]), ("quad9", p[~q8 & ~t6]), ("triangle6", p[t6][:, [0, 1, 2, 4, 5, 7]]))
    else:
        blocks = (("quad", mesh.quads[~tri]), ("triangle", mesh.quads[tri, :3]))
    cells = [(kind, block) for kind, block in blocks if len(block)]
    steps = range(mesh.n_steps)
    vtus = [directory / f"{name}_{k:04d}.vtu" for k in steps]
    pvd = directory / f"{name}.pvd"
    times = [t if t is not None else float(k) for k, t in
             zip(steps, mesh.step_times or [None] * mesh.n_steps)]
    with atomic_paths([*vtus, pvd]) as tmps:
        for tmp, k in zip(tmps, steps):
            u = to_camera(mesh.nodes + mesh.displacements[k], cam) - X0
            meshio.write(tmp, meshio.Mesh(X0, cells, point_data={"displacement": u, "node_label": mesh.node_labels}),
                         file_format="vtu")
        datasets = "\n".join(f'    <DataSet timestep="{t!r}" part="0" file="{v.name}"/>' for t, v in zip(times, vtus))
        tmps[-1].write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" '
                            f'byte_order="LittleEndian">\n  <Collection>\n{datasets}\n  </Collection>\n</VTKFile>\n')
    return [*vtus, pvd]
