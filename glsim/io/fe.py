"""FE results, one entry point: :func:`load_mesh` reads any mesh file as a world-frame
:class:`~glsim.scene.mesh.Mesh` — single-state files through meshio (:mod:`glsim.io.meshfiles`),
time series (Exodus II through netCDF4, ParaView ``.pvd``, XDMF) one load step per stored time
(:func:`load_series`)."""
from __future__ import annotations

import contextlib
from typing import Iterator, Sequence

import numpy as np

from glsim.errors import SceneError
from glsim.io.exodus import open_exodus
from glsim.io.meshfiles import read_mesh_file, require_input_file
from glsim.io.series import (Series, check_displacement, default_displacement, displacement_at, is_time_series, open_pvd,
                             open_xdmf, select_steps, series_surface)
from glsim.scene import Scene
from glsim.scene import mesh as meshmod
from glsim.scene.fields import apply_field, px_per_mm
from glsim.scene.mesh import Mesh, place_mesh
from glsim.scene.model import EXODUS_SUFFIXES


@contextlib.contextmanager
def open_series(path) -> Iterator[Series]:
    """Open an Exodus II, .pvd or XDMF time-series file as a :class:`Series` (closed on exit)."""
    path = require_input_file(path)
    suffix = path.suffix.lower()
    if suffix in EXODUS_SUFFIXES:
        with open_exodus(path) as series:
            yield series
    elif suffix == ".pvd":
        yield open_pvd(path)
    elif suffix in (".xdmf", ".xmf"):
        with open_xdmf(path) as series:
            yield series
    else:
        raise SceneError(str(path), f"suffix {path.suffix!r} is not a time-series format",
                         f"give an Exodus II ({', '.join(EXODUS_SUFFIXES)}), .pvd or XDMF time-series file")


def load_series(path, unit: str = "mm", R=None, t=None, displacement: str | Sequence[str] = (),
                times: Sequence[float] = (), steps: Sequence[int] = ()) -> Mesh:
    """Read an Exodus II, .pvd or XDMF time series as a world-frame Mesh, one load step per
    selected stored time (see the module docstring for step 0), with ``step_times``.

    displacement: one vector field name, or the x, y[, z] component field names ("" or,
    in a 2-D file, a missing z component: zero); default: found by the usual names.
    times (the file's time values) or steps (stored-step indices) select; default all.
    Coordinates and displacements are in `unit`, then placed by place(…, unit, R, t).
    """
    names = (displacement,) if isinstance(displacement, str) else tuple(displacement)
    if len(names) > 3:
        raise SceneError("specimen.mesh.displacement", f"{len(names)} names given",
                         "give one vector field, or 2–3 component fields")
    with open_series(path) as s:
        picked = select_steps(s, times, steps)
        quads, labels, patches = series_surface(s)
        n = len(s.points)
        if picked:
            fields = check_displacement(s, names or default_displacement(s))
            us = [displacement_at(s, fields, k) for k in picked]
        else:
            us = []
        step_times = [float(s.times[k]) for k in picked]
        if us and not np.any(us[0]):
            displacements, step_times = us, step_times
        elif us:
            displacements, step_times = [np.zeros((n, 3))] + us, [None] + step_times
        else:
            displacements, step_times = [], []
        try:
            mesh = Mesh(s.points, quads, s.node_labels, labels, tuple(displacements), tuple(step_times), patches)
        except SceneError as exc:
            raise SceneError(str(s.path), str(exc)) from exc
    return place_mesh(mesh, unit, R, t)


def load_mesh(path, unit: str = "mm", R=None, t=None, point_data_steps: Sequence[str] | None = None,
              displacement_files: Sequence | None = None, csv_files: Sequence | None = None,
              field: str | None = None, roots: Sequence = ()) -> Mesh:
    """Any FE mesh file as a world-frame Mesh: a time series (Exodus II, .pvd, XDMF) with every
    stored time as a load step (:func:`load_series`, fields found by name), any other file through
    :func:`glsim.io.meshfiles.read_mesh_file` with the displacement source given (``roots``: the
    folders besides the file's own that an Abaqus ``*INCLUDE`` may read from)."""
    if is_time_series(path):
        if any(s is not None for s in (point_data_steps, displacement_files, csv_files)):
            raise SceneError(str(path), "holds its own time steps", "read it with glsim.io.fe.load_series("
                             "path, displacement=…, times=…) or give no displacement source")
        return load_series(path, unit, R, t)
    return read_mesh_file(path, unit, R, t, point_data_steps, displacement_files, csv_files, field, roots)


def specimen_mesh(scene: Scene) -> meshmod.Mesh:
    """The scene's FE mesh placed in the world (mm), with all its load steps, and with
    ``specimen.field`` (split along its cracks) added to them."""
    sp = scene.specimen
    if sp.bulge is not None:
        b = sp.bulge
        m = meshmod.bulge(b.radius, b.thickness, b.w0, b.steps, b.n_core, b.n_ring)
    elif sp.plate is not None:
        p = sp.plate
        m = meshmod.plate(p.width, p.height, p.nx, p.ny)
        steps = [np.broadcast_to(np.asarray(tr, float), m.nodes.shape) for tr in p.translations]
        m = meshmod.with_displacements(m, steps)
    else:
        f = sp.mesh  # path, unit and sources were validated by the scene
        if is_time_series(scene.resolve(f.path)):
            m = load_series(scene.resolve(f.path), unit=f.unit, displacement=f.displacement,
                            times=f.times, steps=f.steps)
        elif f.displacement or f.times or f.steps:
            raise SceneError("specimen.mesh.path", f"{f.path} holds no time series (an XDMF file without "
                             "a temporal collection)", "use point_data, files or csv with single-state files")
        else:
            m = load_mesh(
                scene.resolve(f.path), unit=f.unit,
                point_data_steps=list(f.point_data) or None,
                displacement_files=[scene.resolve(x) for x in f.files] or None,
                csv_files=[scene.resolve(x) for x in f.csv] or None, field=f.field or None,
                roots=[scene.base_dir])
    if sp.field is not None:   # in the specimen's own frame, before the placement
        m = apply_field(sp.field, m, lambda X: px_per_mm(scene.cameras[0], sp.R, sp.t, X))
    return meshmod.place_mesh(m, "mm", np.asarray(sp.R, float), np.asarray(sp.t, float))
