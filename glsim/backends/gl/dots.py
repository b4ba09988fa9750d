"""The generator's speckle on the GPU for ``interpolation = "procedural"`` (shaders/procedural.glsl):
its dots sorted into grid cells, uploaded once as two storage buffers, with the grid's uniforms."""
from __future__ import annotations

import numpy as np

from glsim.backends.gl.bindings import storage
from glsim.backends.gl.uniforms import Uniforms


def dot_buffers(ctx, dots) -> tuple:
    """(dots buffer, cells buffer, uniforms) of the speckle ``dots`` (refused if None)."""
    from glsim.scene.speckle import dot_grid
    from glsim.imaging.reference import require_dots

    dots = require_dots(dots)
    grid = dot_grid(dots)
    c = dots.centres[grid.order]
    corner = np.asarray(grid.origin) + np.floor((c - grid.origin) / grid.cell) * grid.cell
    dot_data = np.column_stack([c - corner, dots.radii[grid.order]]).astype(np.float32)
    cell_data = np.column_stack([grid.start, grid.count]).astype(np.int32)
    hi = np.asarray(grid.origin, np.float32)
    uniforms = {"u_grid_origin_hi": tuple(hi.tolist()), "u_grid_origin_lo": tuple((np.asarray(grid.origin) - hi).tolist()),
                "u_grid_cell": grid.cell, "u_grid_dims": grid.dims, "u_dot_edge": dots.edge_px,
                "u_dot_black": dots.black, "u_dot_white": dots.white}
    return ctx.buffer(dot_data.tobytes() or bytes(12)), ctx.buffer(cell_data.tobytes()), Uniforms(uniforms)


def bind_dots(buffers: tuple, prog) -> None:
    """Bind procedural.glsl's storage buffers and write its uniforms to ``prog``."""
    dot_buf, cell_buf, uniforms = buffers
    dot_buf.bind_to_storage_buffer(storage("DOTS"))
    cell_buf.bind_to_storage_buffer(storage("DOT_CELLS"))
    uniforms.write(prog)
