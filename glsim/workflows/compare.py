"""``glsim compare RESULT --truth DIR``: a DIC result against glsim's ground truth.

RESULT is a CSV (fields separated by ``,``, ``;``, tabs or spaces, as the header row shows; with
``;`` or tabs a decimal comma is read too) with a header row: ``u, v`` (the subset centres, pixel coordinates of camera 0's
reference image) and ``X, Y, Z`` (measured positions at the load step, mm, camera 0's frame)
and/or ``U, V, W`` (measured displacements from the reference state, mm); an optional ``valid``
column (0/1). The ``measured_*.npz`` that ``glsim verify`` keeps from pyvale is read too
(``ss_x``, ``ss_y``, ``X``/``U`` per state, ``valid``; its arrays' sizes are checked against their
headers and the memory before they are read). Every u, v must be a finite number, and so must
every measured value of a valid point (mark a point invalid rather than write NaN into a valid
one). DIR is what ``glsim render`` or a library variant wrote: its ``scene.json`` gives the
mesh, the displacements and camera 0.

The truth at each subset centre is exact: camera 0's ray through (u, v) met with the undeformed
mesh, that material point moved with the FE displacement of the step
(:func:`glsim.scene.locate.points_truth`). Errors are measured − true per component, in mm and in px
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
from glsim.io.npzfile import NpzError, read_npz
from glsim.io.truth import mesh_geometry
from glsim.scene.locate import points_truth
from glsim.workflows.library.manifest import counted
from glsim.scene import load_scene
from glsim.io.fe import specimen_mesh
from glsim.workflows.figures import save_figure

COMPONENTS = {"X": ("X", "Y", "Z"), "U": ("U", "V", "W")}


def read_result(path: str | Path, state: int = -1) -> dict[str, np.ndarray]:
    """{"uv": (n, 2), "valid": (n,), and "X" and/or "U": (n, 3)} from a CSV or a verify .npz
    (``state``: which of its states, default the last)."""
    path = Path(path)
    if not path.is_file():
        raise GlsimError(f"{path}: DIC result not found; give a CSV (u, v, X, Y, Z and/or U, V, W) or a "
                         "measured_*.npz from glsim verify")
    if path.suffix == ".npz":
        return _finite(_read_npz(path, state), path, lambda i: f"point {i}")
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
    return _finite(out, path, lambda i: f"data row {i + 1}")


def _finite(result: dict, path: Path, where) -> dict:
    """``result``, refused (GlsimError naming ``where(i)`` of the first point and the column) if a
    u, v or a valid point's measured value is not a finite number."""
    checks = [("u, v", result["uv"], np.ones(len(result["uv"]), bool))]
    checks += [("/".join(COMPONENTS[k]), result[k], result["valid"]) for k in COMPONENTS if k in result]
    for name, values, rows in checks:
        bad = rows & ~np.isfinite(values).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise GlsimError(f"{path}: {where(i)} has {name} = {', '.join(f'{v:g}' for v in values[i])}, not finite "
                             "numbers — give finite values, or mark the point invalid (valid = 0; u, v stay finite)")
    return result


NPZ_ARRAYS = ("ss_x", "ss_y", "valid")


def _read_npz(path: Path, state: int) -> dict[str, np.ndarray]:
    """:func:`read_result` of verify's ``measured_*.npz``: ``ss_x``, ``ss_y`` (n,), ``valid`` (S, n)
    and ``X``/``U`` (S, n, 3), their sizes checked before they are read."""
    def problem(members: dict) -> str:
        n = members["ss_x"].shape if len(members["ss_x"].shape) == 1 else (-1,)
        want = {"ss_x": n, "ss_y": n, "valid": (members["valid"].shape[:1] or (0,)) + n}
        want.update({k: want["valid"] + (3,) for k in ("X", "U") if k in members})
        bad = next((k for k in want if members[k].shape != want[k] or members[k].dtype.kind not in "biuf"), None)
        return f"{bad} is {members[bad].dtype} {members[bad].shape}, not numbers of shape {want[bad]}" if bad else ""

    try:
        z = read_npz(path, NPZ_ARRAYS, COMPONENTS, check=problem)
    except NpzError as exc:
        raise GlsimError(f"{exc}; give a measured_*.npz written by verify/dic.py, or a CSV") from None
    states = len(z["valid"])
    if not -states <= state < states:
        raise GlsimError(f"{path}: has {states} states; state {state} is not one of them")
    out = {"uv": np.stack([z["ss_x"], z["ss_y"]], axis=1).astype(np.float64), "valid": z["valid"][state].astype(bool)}
    out.update({key: np.asarray(z[key][state], np.float64) for key in COMPONENTS if key in z})
    return out


def _read_rows(path: Path) -> tuple[list[list[str]], str | None]:
    """The non-blank rows of a CSV and its separator, the first of ``;``, tab, ``,`` in the header
    row (None: whitespace). GlsimError for a file that is not UTF-8 text or not CSV."""
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise GlsimError(f"{path}: is not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}) — "
                         "save the DIC result as UTF-8 (or ASCII) CSV") from None
    lines = [line for line in text.splitlines() if line.strip()]
    sep = next((s for s in (";", "\t", ",") if lines and s in lines[0]), None)
    if sep is None:
        return [line.split() for line in lines], None
    source = counted(lines)
    try:
        return list(csv.reader(source, delimiter=sep)), sep
    except csv.Error as exc:
        raise GlsimError(f"{path}: line {source.count} of its non-blank lines is not CSV ({exc}) — give one "
                         "number per field") from None


def truth_at(truth_dir: str | Path, uv: np.ndarray, step: int):
    """The exact truth (:class:`~glsim.scene.locate.PointTruth`) at camera-0 reference pixels ``uv``."""
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
    """Read, compare, write ``compare.json``, ``compare.md`` and ``compare.png`` to ``out`` (a
    directory; checked before anything is read)."""
    out = Path(out) if out else Path(result_path).parent / "compare"
    if out.exists() and not out.is_dir():
        raise GlsimError(f"-o {out}: is a file, not a directory — give a directory for compare.json, compare.md "
                         "and compare.png")
    result = read_result(result_path)
    truth, cam = truth_at(truth_dir, result["uv"], step)
    res = compare(result, truth, cam)
    text = markdown(res, str(result_path), str(truth_dir))
    try:
        out.mkdir(parents=True, exist_ok=True)
        io.write_text(out / "compare.json", json.dumps(res, indent=2) + "\n")
        io.write_text(out / "compare.md", text)
        plot_map(result, truth, out / "compare.png")
    except OSError as exc:
        raise GlsimError(f"-o {out}: cannot be written ({exc.strerror or exc}) — give a writable directory"
                         + (" with free space" if exc.errno == 28 else "")) from None
    return {**res, "markdown": text, "out": str(out)}
