"""2-D DIC of a glsim sweep exchange folder with pyvale; runs in .venv-verify, never imports glsim.

    .venv-verify/bin/python verify/dic2d.py EXCHANGE_DIR

Reads ``manifest.json`` (format ``glsim-sweep/1``): the image sequences (each a reference
image and one deformed image per imposed shift), the ROI, the seed, the
``pyvale.dic.calculate_2d`` keyword arguments common to every run and the runs (name and
subset size). For every sequence and run it calls ``calculate_2d(reference, [deformed…])``;
pyvale writes one CSV per deformed image under ``EXCHANGE/dic/<sequence>/<run>/``, which
this script gathers with ``pyvale.dic.import_2d`` into
``EXCHANGE/measured_<sequence>_<run>.npz``:

- ``ss_x``, ``ss_y`` (n,): subset centres on the reference image, px (pixel centres at
  integers);
- ``u``, ``v`` (shifts, n): measured displacement, px, in the order of the manifest's shifts;
- ``valid`` (shifts, n): converged, ZNCC ≥ the threshold, finite;
- ``cost`` (ZNCC), ``niter`` (shifts, n); ``seconds`` (the ``calculate_2d`` call) and
  ``pyvale_version``.

With a ``strain`` table in the manifest (``window_size``, ``window_element``,
``strain_formulation``: the keyword arguments of ``pyvale.strain.calculate_2d``), the displacements
also go through pyvale's strain (the invalid subsets as NaN, which pyvale leaves out of every
window), and the npz also holds ``strain_x``, ``strain_y`` (m,): the strain points (window
centres, px on the reference image) and ``exx``, ``eyy``, ``exy`` (tensor shear), ``strain_valid``
(shifts, m), in the manifest's shift order.
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


def run(exchange: Path, manifest: dict, seq: dict, spec: dict) -> dict:
    """One ``calculate_2d`` call: sequence ``seq`` with run ``spec`` (name, subset_size)."""
    import pyvale.dic as dic

    reference = exchange / seq["reference"]
    deformed = [exchange / name for name in seq["deformed"]]
    roi = load_roi(exchange, manifest)
    out = fresh_dir(exchange / "dic" / seq["name"] / spec["name"])
    kwargs = {**manifest["calculate_2d"], "subset_size": spec["subset_size"]}
    prefix = "dic_results_"
    t0 = time.perf_counter()
    dic.calculate_2d(reference=reference, deformed=deformed, roi_mask=roi, seed=manifest["seed"],
                     output_basepath=str(out), output_prefix=prefix, output_delimiter=",",
                     print_level=0, **kwargs)
    seconds = time.perf_counter() - t0
    # One CSV per deformed image, named after it: read them back in the manifest's shift order.
    files = [out / f"{prefix}{Path(name).stem}.csv" for name in seq["deformed"]]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise RuntimeError(f"pyvale wrote no result for {missing} (found {sorted(p.name for p in out.glob('*'))})")
    with contextlib.redirect_stdout(io.StringIO()):   # import_2d logs every file after the first
        res = dic.import_2d(files, delimiter=",", layout="column", print_level=0)
    u, v = np.asarray(res.u_px, np.float64), np.asarray(res.v_px, np.float64)
    cost = np.asarray(res.cost, np.float64)
    valid = (np.asarray(res.converged).astype(bool) & (cost >= kwargs["threshold"])
             & np.isfinite(u) & np.isfinite(v))
    out = {"ss_x": np.asarray(res.ss_x), "ss_y": np.asarray(res.ss_y), "u": u, "v": v, "valid": valid,
           "cost": cost, "niter": np.asarray(res.niter), "seconds": np.float64(seconds),
           "pyvale_version": np.str_(version("pyvale"))}
    if manifest.get("strain"):
        out.update(strain(files, out, manifest["strain"], fresh_dir(exchange / "strain" / seq["name"] / spec["name"])))
    return out


def strain(files: list[Path], m: dict, kwargs: dict, out: Path) -> dict:
    """pyvale's strain of the DIC results ``files`` (one per shift), the subsets ``m`` marks
    invalid set to NaN so that no window uses them; the components at every strain point."""
    import pyvale.dic as dic
    import pyvale.strain as pstrain

    with contextlib.redirect_stdout(io.StringIO()):
        grid = dic.import_2d(files, delimiter=",", layout="matrix", print_level=0)
    # the matrix layout's (row, column) of every subset of the column layout above
    keep = valid_on_grid(grid.ss_x, grid.ss_y, m, grid.u_px.shape)
    grid.u_px = np.where(keep, grid.u_px, np.nan)
    grid.v_px = np.where(keep, grid.v_px, np.nan)
    prefix = "strain_"
    with contextlib.redirect_stdout(io.StringIO()):
        pstrain.calculate_2d(grid, window_size=int(kwargs["window_size"]), window_element=int(kwargs["window_element"]),
                             strain_formulation=str(kwargs["strain_formulation"]), output_basepath=str(out),
                             output_prefix=prefix, output_delimiter=",", print_level=0)
    return strain_arrays(out, prefix, len(files), pstrain.import_2d)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    exchange = Path(argv[0])
    manifest = json.loads((exchange / "manifest.json").read_text())
    if manifest.get("format") != "glsim-sweep/1":
        print(f"verify/dic2d.py: {exchange}/manifest.json is not a glsim-sweep/1 manifest", file=sys.stderr)
        return 2
    for seq in manifest["sequences"]:
        for spec in manifest["runs"]:
            arrays = run(exchange, manifest, seq, spec)
            save_npz(exchange / f"measured_{seq['name']}_{spec['name']}.npz", arrays)
            n, ok = arrays["valid"].shape[1], int(np.all(arrays["valid"], axis=0).sum())
            print(f"verify/dic2d.py: {seq['name']:20s} {spec['name']}: {ok}/{n} subsets valid at every "
                  f"shift, {float(arrays['seconds']):.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
