"""``glsim compare RESULT --truth DIR``: a DIC result against glsim's ground truth.

RESULT is a CSV (fields separated by ``,``, ``;``, tabs or spaces, as the header row shows; with
``;`` or tabs a decimal comma is read too) with a header row: ``u, v`` (the subset centres, pixel coordinates of camera 0's
reference image) and ``X, Y, Z`` (measured positions at the load step, mm, camera 0's frame)
and/or ``U, V, W`` (measured displacements from the reference state, mm); an optional ``valid``
column (0/1). The ``measured_*.npz`` that ``glsim verify`` keeps from pyvale is read too
(``ss_x``, ``ss_y``, ``X``/``U`` per state, ``valid``). DIR is what ``glsim render`` or a library
variant wrote: its ``scene.json`` gives the mesh, the displacements and camera 0.

The truth at each subset centre is exact: camera 0's ray through (u, v) met with the undeformed
mesh, that material point moved with the FE displacement of the step
(:func:`glsim.io.truth.points_truth`). Errors are measured − true per component, in mm and in px
(mm / M, M = mean Z / √(fx·fy) of the compared points: the mean scale of camera 0 there).
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.io.truth import mesh_geometry, points_truth
from glsim.scene import load_scene
from glsim.io.fe import specimen_mesh

COMPONENTS = {"X": ("X", "Y", "Z"), "U": ("U", "V", "W")}


def read_result(path: str | Path, state: int = -1) -> dict[str, np.ndarray]:
    """{"uv": (n, 2), "valid": (n,), and "X" and/or "U": (n, 3)} from a CSV or a verify .npz
    (``state``: which of its states, default the last)."""
    path = Path(path)
    if not path.is_file():
        raise GlsimError(f"{path}: DIC result not found; give a CSV (u, v, X, Y, Z and/or U, V, W) or a "
                         "measured_*.npz from glsim verify")
    if path.suffix == ".npz":
        with np.load(path) as z:
            missing = [k for k in ("ss_x", "ss_y", "valid") if k not in z]
            if missing:
                raise GlsimError(f"{path}: has no {', '.join(missing)}; give a measured_*.npz written by "
                                 "verify/dic.py, or a CSV")
            out = {"uv": np.stack([z["ss_x"], z["ss_y"]], axis=1).astype(np.float64),
                   "valid": np.asarray(z["valid"])[state].astype(bool)}
            for key in ("X", "U"):
                if key in z:
                    out[key] = np.asarray(z[key][state], np.float64)
        return out
    rows, sep = _read_rows(path)
    if not rows:
        raise GlsimError(f"{path}: empty; give a header row u, v, X, Y, Z and/or U, V, W")
    head = [h.strip() for h in rows[0]]
    col = {h: i for i, h in enumerate(head)}
    if not {"u", "v"} <= set(col) or not any(set(c) <= set(col) for c in COMPONENTS.values()):
        raise GlsimError(f"{path}: the header has {', '.join(head)}; needed: u, v and X, Y, Z and/or U, V, W "
                         "(mm, camera 0's frame)")
    if len(rows) == 1:
        raise GlsimError(f"{path}: no data rows, only the header; give one row per subset centre")
    short = next(((i, len(r)) for i, r in enumerate(rows[1:], 1) if len(r) != len(head)), None)
    if short:
        raise GlsimError(f"{path}: data row {short[0]} has {short[1]} values, the header {len(head)}; every row "
                         "needs one value per header column")
    decimal = "," if sep in (";", "\t") else "."      # a decimal comma where ',' does not separate
    try:
        data = np.array([[float(x.replace(decimal, ".")) for x in r] for r in rows[1:]], np.float64)
    except ValueError as exc:
        raise GlsimError(f"{path}: not all values are numbers ({exc})") from None
    out = {"uv": data[:, [col["u"], col["v"]]],
           "valid": data[:, col["valid"]] != 0 if "valid" in col else np.ones(len(data), bool)}
    for key, names in COMPONENTS.items():
        if set(names) <= set(col):
            out[key] = data[:, [col[n] for n in names]]
    return out


def _read_rows(path: Path) -> tuple[list[list[str]], str | None]:
    """The non-blank rows of a CSV and its separator, the first of ``;``, tab, ``,`` in the header
    row (None: whitespace)."""
    with open(path, newline="", encoding="utf-8-sig") as f:
        lines = [line for line in f.read().splitlines() if line.strip()]
    sep = next((s for s in (";", "\t", ",") if lines and s in lines[0]), None)
    if sep is None:
        return [line.split() for line in lines], None
    return [r for r in csv.reader(lines, delimiter=sep)], sep


def truth_at(truth_dir: str | Path, uv: np.ndarray, step: int):
    """The exact truth (:class:`~glsim.io.truth.PointTruth`) at camera-0 reference pixels ``uv``."""
    truth_dir = Path(truth_dir)
    scene_json = truth_dir / "scene.json" if truth_dir.is_dir() else truth_dir
    scene = load_scene(scene_json)
    mesh = specimen_mesh(scene)
    if not 0 <= step < mesh.n_steps:
        raise GlsimError(f"--step {step}: {scene_json} has load steps 0…{mesh.n_steps - 1}")
    return points_truth(mesh_geometry(mesh), scene.cameras[0], uv, step), scene.cameras[0]


def compare(result: dict, truth, cam) -> dict:
    """Per component: mean, std and max |measured − true| in mm and px, on the points valid in both."""
    ok = result["valid"] & truth.valid
    if not ok.any():
        raise GlsimError("no subset centre of the DIC result lies on the specimen in the truth: are u, v "
                         "camera 0's reference-image pixels?")
    scale = float(np.mean(truth.X_undeformed[ok, 2]) / math.sqrt(cam.fx * cam.fy))
    rows = []
    for key, names in COMPONENTS.items():
        if key not in result:
            continue
        true = truth.X_deformed if key == "X" else truth.displacement
        d = result[key][ok] - true[ok]
        for j, name in enumerate(names):
            mean, std, worst = float(d[:, j].mean()), float(d[:, j].std()), float(np.abs(d[:, j]).max())
            rows.append({"dir": name, "mean_mm": mean, "std_mm": std, "max_abs_mm": worst,
                         "mean_px": mean / scale, "std_px": std / scale, "max_abs_px": worst / scale})
    return {"n_points": int(len(ok)), "n_compared": int(ok.sum()), "mm_per_px": scale, "step": truth.step,
            "rows": rows}


def markdown(res: dict, result_path: str, truth_dir: str) -> str:
    lines = [f"# {result_path} against the truth of {truth_dir}", "",
             f"Load step {res['step']}; {res['n_compared']} of {res['n_points']} points compared; "
             f"px = mm / {res['mm_per_px']:.5g} (camera 0's mean scale there).", "",
             "| component | mean (mm) | std (mm) | max \\|error\\| (mm) | mean (px) | std (px) | max \\|error\\| (px) |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['dir']} | {r['mean_mm']:.3e} | {r['std_mm']:.3e} | {r['max_abs_mm']:.3e} | {r['mean_px']:.3e} "
              f"| {r['std_px']:.3e} | {r['max_abs_px']:.3e} |" for r in res["rows"]]
    return "\n".join(lines) + "\n"


def plot_map(result: dict, truth, path: Path) -> Path:
    """Error magnitude (mm) at each compared subset centre, on camera 0's reference image axes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from glsim.evaluation.report import save_figure

    key = "U" if "U" in result else "X"
    true = truth.displacement if key == "U" else truth.X_deformed
    ok = result["valid"] & truth.valid
    err = np.linalg.norm(result[key][ok] - true[ok], axis=1)
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    sc = ax.scatter(result["uv"][ok, 0], result["uv"][ok, 1], c=err, s=6, cmap="viridis")
    ax.invert_yaxis()
    ax.set_aspect("equal")
    ax.set_xlabel("u (px, camera 0 reference)")
    ax.set_ylabel("v (px)")
    bar = fig.colorbar(sc, ax=ax, label=f"|{key} measured − true| (mm)")
    bar.ax.ticklabel_format(useOffset=False)      # the errors themselves, never "1e-13 + 1e-2"
    return save_figure(fig, path, dpi=100)


def run(result_path: str | Path, truth_dir: str | Path, step: int, out: str | Path | None) -> dict:
    """Read, compare, write ``compare.json``, ``compare.md`` and ``compare.png`` to ``out``."""
    result = read_result(result_path)
    truth, cam = truth_at(truth_dir, result["uv"], step)
    res = compare(result, truth, cam)
    out = Path(out) if out else Path(result_path).parent / "compare"
    text = markdown(res, str(result_path), str(truth_dir))
    io.write_text(out / "compare.json", json.dumps(res, indent=2) + "\n")
    io.write_text(out / "compare.md", text)
    plot_map(result, truth, out / "compare.png")
    return {**res, "markdown": text, "out": str(out)}
