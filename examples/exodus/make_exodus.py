"""Write ``plate_out.e``: a small MOOSE-like Exodus II result for glsim's time-series reader.

A 100 × 40 mm plate in metres (as MOOSE writes it), 20 × 8 QUAD4 elements in two element
blocks ("left" for x < 0, "right" for x > 0), node numbers from 1001 and element numbers from
501 (the node_num_map / elem_num_map), and 11 stored times 0, 10, …, 100 s of tension plus
in-plane bending, ramped linearly from zero:

    ux = s·(ε·x − κ·x·y),   uy = s·(−ν·ε·y + κ/2·(x² + ν·y²)),   s = t / 100 s,

with ε = 0.2 %, κ = 0.2 /m, ν = 0.3: at t = 100 s the plate's ends move ±0.1 mm (tension),
±0.2 mm (bending) along x and 0.25 mm along y. Nodal fields disp_x, disp_y (no disp_z: a 2-D
result) and strain_xx, each (time, node), in the layout of the Exodus II netCDF model.

Run ``python examples/exodus/make_exodus.py`` to regenerate the committed file; needs netCDF4.
"""
from pathlib import Path

import numpy as np
import netCDF4

WIDTH, HEIGHT, NX, NY = 0.100, 0.040, 20, 8          # m
STRAIN, CURVATURE, POISSON = 0.002, 0.2, 0.3
TIMES = np.linspace(0.0, 100.0, 11)                   # s
OUT = Path(__file__).resolve().parent / "plate_out.e"


def mesh():
    """Nodes (N, 2) in m, row by row from the bottom-left corner, and the two blocks' QUAD4
    connectivity (0-based, counter-clockwise seen from +z)."""
    x, y = np.meshgrid(np.linspace(-WIDTH / 2, WIDTH / 2, NX + 1), np.linspace(-HEIGHT / 2, HEIGHT / 2, NY + 1))
    index = np.arange(x.size).reshape(x.shape)
    quads = np.stack([index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]], axis=-1)
    left, right = quads[:, :NX // 2].reshape(-1, 4), quads[:, NX // 2:].reshape(-1, 4)
    return np.stack([x.ravel(), y.ravel()], axis=1), left, right


def displacement(xy: np.ndarray, t: float) -> np.ndarray:
    """(ux, uy) in m at time t, per node."""
    x, y, s = xy[:, 0], xy[:, 1], t / TIMES[-1]
    return s * np.stack([STRAIN * x - CURVATURE * x * y,
                         -POISSON * STRAIN * y + CURVATURE / 2 * (x ** 2 + POISSON * y ** 2)], axis=1)


def write(path: Path = OUT) -> Path:
    xy, left, right = mesh()
    n, blocks = len(xy), [("left", left), ("right", right)]
    u = np.stack([displacement(xy, t) for t in TIMES])                       # (T, N, 2)
    strain = np.stack([t / TIMES[-1] * (STRAIN - CURVATURE * xy[:, 1]) for t in TIMES])
    fields = {"disp_x": u[..., 0], "disp_y": u[..., 1], "strain_xx": strain}
    with netCDF4.Dataset(path, "w", format="NETCDF3_64BIT_OFFSET") as ds:
        ds.title = "glsim example: 100 x 40 mm plate, tension + bending, m"
        ds.api_version, ds.version, ds.floating_point_word_size, ds.file_size = 8.0, 8.0, 8, 1
        for name, size in (("len_string", 33), ("len_name", 33), ("len_line", 81), ("four", 4),
                           ("time_step", None), ("num_dim", 2), ("num_nodes", n),
                           ("num_elem", len(left) + len(right)), ("num_el_blk", 2),
                           ("num_nod_var", len(fields))):
            ds.createDimension(name, size)
        ds.createVariable("time_whole", "f8", ("time_step",))[:] = TIMES
        ds.createVariable("eb_names", "S1", ("num_el_blk", "len_name"))[:] = netCDF4.stringtochar(
            np.array([name for name, _ in blocks], dtype="S33"))
        ids = ds.createVariable("eb_prop1", "i4", ("num_el_blk",))
        ids.setncattr("name", "ID")
        ids[:] = [1, 2]
        for i, (_, conn) in enumerate(blocks, 1):
            ds.createDimension(f"num_el_in_blk{i}", len(conn))
            ds.createDimension(f"num_nod_per_el{i}", 4)
            var = ds.createVariable(f"connect{i}", "i4", (f"num_el_in_blk{i}", f"num_nod_per_el{i}"))
            var.elem_type = "QUAD4"
            var[:] = conn + 1                                                  # 1-based
        ds.createVariable("coordx", "f8", ("num_nodes",))[:] = xy[:, 0]
        ds.createVariable("coordy", "f8", ("num_nodes",))[:] = xy[:, 1]
        ds.createVariable("node_num_map", "i4", ("num_nodes",))[:] = 1001 + np.arange(n)
        ds.createVariable("elem_num_map", "i4", ("num_elem",))[:] = 501 + np.arange(len(left) + len(right))
        ds.createVariable("name_nod_var", "S1", ("num_nod_var", "len_name"))[:] = netCDF4.stringtochar(
            np.array(list(fields), dtype="S33"))
        for j, values in enumerate(fields.values(), 1):
            ds.createVariable(f"vals_nod_var{j}", "f8", ("time_step", "num_nodes"))[:] = values
    return path


if __name__ == "__main__":
    print(write())
