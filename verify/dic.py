"""Stereo DIC of a glsim exchange folder with pyvale; runs in .venv-verify and never imports glsim.

    .venv-verify/bin/python verify/dic.py EXCHANGE_DIR

Reads ``manifest.json`` (images per state and bit depth, ROI, seed, calibration, the
``pyvale.dic.calculate_3d`` keyword arguments and the runs), and for each run calls
``calculate_3d`` on the reference pair (state 0) and the deformed pairs. pyvale writes one CSV
per state under ``EXCHANGE/dic/<run>/``; this script gathers them into
``EXCHANGE/measured_<run>.npz``:

- ``ss_x``, ``ss_y`` (n,): subset centres on camera 0's reference image, px (pixel centres at
  integers);
- ``X`` (states, n, 3): triangulated positions, mm, camera 0's frame (each state's own);
- ``U`` (states, n, 3): displacements from the reference state, mm;
- ``valid`` (states, n): converged and above the ZNCC threshold in the temporal and stereo
  matches, finite;
- ``cost``, ``stereo_cost``, ``epi_dist_px`` (states, n); ``seconds`` (the ``calculate_3d``
  call), ``pyvale_version``.

With a ``strain`` table in the manifest (``window_size``, ``window_element``,
``strain_formulation``: the keyword arguments of ``pyvale.strain.calculate_3d``), the results also
go through pyvale's surface strain (the invalid subsets as NaN, which pyvale leaves out of every
window), and the npz also holds ``strain_x``, ``strain_y`` (m,): the strain points (px on camera
0's reference image) and ``exx``, ``eyy``, ``exy`` (tensor shear, in pyvale's tangent basis),
``strain_valid`` (states, m).
"""
from __future__ import annotations

import contextlib
import io
import json
import sys
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np

from exchange import strain_arrays, valid_on_grid, fresh_dir, load_roi, save_npz


def load_calibration(path: Path):
    """``pyvale.calib.Calib`` from the exchange's calibration.json (px, mm, degrees)."""
    from pyvale.calib import Calib, CamIntrinsics

    data = json.loads(path.read_text())

    def cam(d: dict) -> CamIntrinsics:
        return CamIntrinsics(fx=d["fx"], fy=d["fy"], fs=d["fs"], cx=d["cx"], cy=d["cy"],
                             distortion=np.asarray(d["distortion"], dtype=np.float64))

    return Calib(cam0=cam(data["cam0"]), cam1=cam(data["cam1"]),
                 translation=np.asarray(data["translation"], dtype=np.float64),
                 rotation=np.asarray(data["rotation"], dtype=np.float64))


def gather(results, threshold: float) -> dict[str, np.ndarray]:
    """``pyvale.dic.Results`` (column layout, states × subsets) → the measured_<run>.npz arrays."""
    st = results.stereo
    X = np.stack([st.x_mm, st.y_mm, st.z_mm], axis=-1)
    U = np.stack([st.u_mm, st.v_mm, st.w_mm], axis=-1)
    valid = (results.converged.astype(bool) & st.converged.astype(bool)
             & (results.cost >= threshold) & (st.cost >= threshold)
             & np.all(np.isfinite(X), axis=-1) & np.all(np.isfinite(U), axis=-1))
    return {"ss_x": np.asarray(results.ss_x), "ss_y": np.asarray(results.ss_y), "X": X, "U": U,
            "valid": valid, "cost": results.cost, "stereo_cost": st.cost, "epi_dist_px": st.epi_dist_px}


def run(exchange: Path, manifest: dict, spec: dict) -> dict:
    """One ``calculate_3d`` run (``spec``: name, shape_function, bit_depth); returns its arrays."""
    import pyvale.dic as dic

    bits = str(spec["bit_depth"])
    images = [[exchange / name for name in s["images"][bits]] for s in manifest["states"]]
    roi = load_roi(exchange, manifest)
    out = fresh_dir(exchange / "dic" / spec["name"])
    kwargs = dict(manifest["calculate_3d"])
    t0 = time.perf_counter()
    dic.calculate_3d(reference=images[0], deformed=[[pair[c] for pair in images[1:]] for c in (0, 1)],
                     roi_mask=roi, calibration=load_calibration(exchange / manifest["calibration"]),
                     seed=manifest["seed"], shape_function=spec["shape_function"],
                     output_basepath=str(out), print_level=0, **kwargs)
    seconds = time.perf_counter() - t0
    files = sorted(out.glob("*.csv"))   # one per state, named after camera 0's images
    if len(files) != len(images):
        raise RuntimeError(f"pyvale wrote {len(files)} result files for {len(images)} states in {out}")
    results = dic.import_3d(files, delimiter=",", layout="column", print_level=0)
    out = {**gather(results, kwargs["threshold"]), "seconds": np.float64(seconds),
           "pyvale_version": np.str_(version("pyvale"))}
    if manifest.get("strain"):
        out.update(strain(files, out, manifest["strain"], fresh_dir(exchange / "strain" / spec["name"])))
    return out


def strain(files: list[Path], m: dict, kwargs: dict, out: Path) -> dict:
    """pyvale's surface strain of the stereo results ``files`` (one per state), the subsets ``m``
    marks invalid set to NaN so that no window uses them; the components at every strain point."""
    import pyvale.dic as dic
    import pyvale.strain as pstrain

    with contextlib.redirect_stdout(io.StringIO()):
        grid = dic.import_3d(files, delimiter=",", layout="matrix", print_level=0)
    keep = valid_on_grid(grid.ss_x, grid.ss_y, m, grid.stereo.u_mm.shape)
    st = grid.stereo
    for name in ("u_mm", "v_mm", "w_mm", "x_mm", "y_mm", "z_mm"):
        setattr(st, name, np.where(keep, getattr(st, name), np.nan))
    prefix = "strain_"
    with contextlib.redirect_stdout(io.StringIO()):
        pstrain.calculate_3d(grid, window_size=int(kwargs["window_size"]), window_element=int(kwargs["window_element"]),
                             strain_formulation=str(kwargs["strain_formulation"]), output_basepath=str(out),
                             output_prefix=prefix, output_delimiter=",", print_level=0)
    return strain_arrays(out, prefix, len(files), pstrain.import_3d)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    exchange = Path(argv[0])
    manifest = json.loads((exchange / "manifest.json").read_text())
    for spec in manifest["runs"]:
        arrays = run(exchange, manifest, spec)
        save_npz(exchange / f"measured_{spec['name']}.npz", arrays)
        n, ok = arrays["valid"].shape[1], int(np.all(arrays["valid"], axis=0).sum())
        print(f"verify/dic.py: {spec['name']}: {spec['shape_function']}, {spec['bit_depth']}-bit, "
              f"{ok}/{n} subsets valid in every state, {float(arrays['seconds']):.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
