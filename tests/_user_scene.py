"""The kind of scene a new user writes by hand (issue 9): a VTU plate with one displacement
array per load step, a TOML scene naming it, rendered on the CPU at a small size."""
from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from glsim.scene.mesh import plate

WIDTH, HEIGHT = 100.0, 50.0          # mm
FIRST_LABEL = 101                    # node labels 101, 102, … (point data "node_id")


def write_mesh(path: Path, arrays: dict[str, np.ndarray] | None = None, nx: int = 10, ny: int = 5) -> dict:
    """A 100 × 50 mm plate as VTU with node labels and the displacement arrays (default u1, u2:
    totals from the reference of a 0.1 % and 0.2 % stretch along x). Returns the arrays."""
    m = plate(WIDTH, HEIGHT, nx, ny)
    nodes = np.array(m.nodes)
    if arrays is None:
        arrays = {f"u{k}": np.c_[nodes[:, 0] * 1e-3 * k, np.zeros((len(nodes), 2))] for k in (1, 2)}
    labels = np.arange(FIRST_LABEL, FIRST_LABEL + len(nodes))
    meshio.write(path, meshio.Mesh(nodes, [("quad", np.array(m.quads))],
                                   point_data={"node_id": labels, **arrays}))
    return arrays


def n_nodes(nx: int = 10, ny: int = 5) -> int:
    return (nx + 1) * (ny + 1)


CAMERA = """[[cameras]]
name = "cam0"
size = [80, 60]
fx = 400.0
fy = 400.0
cx = 39.5
cy = 29.5
"""

SCENE = CAMERA + """
[specimen.mesh]
path = "plate.vtu"
point_data = {point_data}

[specimen.pose]
t = [0.0, 0.0, 800.0]
{extra}
[render]
backend = "cpu"
mode = "{mode}"
"""


def write_scene(directory: Path, point_data=("u1", "u2"), extra: str = "", mode: str = "exact",
                arrays: dict | None = None, mesh: bool = True) -> Path:
    """``directory/plate.vtu`` (unless ``mesh`` is False) and ``directory/scene.toml``; returns
    the scene file. ``extra``: more TOML (e.g. a [speckle] table) before [render]."""
    directory.mkdir(parents=True, exist_ok=True)
    if mesh:
        write_mesh(directory / "plate.vtu", arrays)
    names = "[" + ", ".join(f'"{n}"' for n in point_data) + "]"
    path = directory / "scene.toml"
    path.write_text(SCENE.format(point_data=names, extra=extra, mode=mode))
    return path


def snapshot(directory: Path) -> dict[str, bytes]:
    """Every file under ``directory`` (hidden ones too) and its bytes; {} if it does not exist."""
    if not directory.exists():
        return {}
    return {p.relative_to(directory).as_posix(): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}
