"""A library's geometry files (``geometry/{hash}.npz``): per distinct specimen the placed
undeformed nodes, quads, element labels, the displacements of the rendered load steps and a
quadratic mesh's patches — what, with a truth file's (element, ξ, η), gives every position."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.io.hashes import sha256_bytes
from glsim.io.truthcodec import TruthFileError


# ---- geometry files -------------------------------------------------------------------------------

def geometry_arrays(nodes, quads, displacements: dict[int, np.ndarray], element_labels=None, patches=None) -> dict:
    """The arrays of a geometry file: placed undeformed nodes (N, 3) mm, quads (M, 4), the
    displacements (S, N, 3) of the load steps ``steps`` (S,), element labels (M,) and, for a
    quadratic mesh only, its patches (M, 9) (:mod:`glsim.scene.quadratic`)."""
    steps = sorted(displacements)
    arrays = {"nodes": np.asarray(nodes, np.float64), "quads": np.asarray(quads, np.int64),
              "steps": np.asarray(steps, np.int64),
              "displacements": np.stack([np.asarray(displacements[s], np.float64) for s in steps]) if steps
              else np.zeros((0,) + np.shape(nodes)),
              "element_labels": np.asarray(element_labels if element_labels is not None
                                           else np.arange(len(quads)), np.int64)}
    if patches is not None:
        arrays["patches"] = np.asarray(patches, np.int64)
    return arrays


def geometry_bytes(arrays: dict) -> bytes:
    """A geometry file's bytes (an .npz, deflate level 1; deterministic: fixed zip timestamps)."""
    import io as _io
    import zipfile
    buf = _io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
        for name, a in arrays.items():
            item = _io.BytesIO()
            np.lib.format.write_array(item, np.ascontiguousarray(a), allow_pickle=False)
            info = zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, item.getvalue())
    return buf.getvalue()


@dataclass(frozen=True, eq=False)
class Geometry:
    nodes: np.ndarray
    quads: np.ndarray
    steps: tuple[int, ...]
    displacements: np.ndarray
    element_labels: np.ndarray
    patches: np.ndarray | None = None   # a quadratic mesh's (M, 9) patches (glsim.scene.quadratic)

    def deformed(self, step: int) -> np.ndarray:
        if step not in self.steps:
            raise TruthFileError(f"load step {step} is not in the geometry file (it holds steps "
                                 f"{list(self.steps)}); ask for one of those")
        return self.nodes + self.displacements[self.steps.index(step)]


GEOMETRY_ARRAYS = ("nodes", "quads", "steps", "displacements", "element_labels")


def read_geometry(path: str | Path, sha256: str | None = None) -> Geometry:
    """The geometry file at ``path``, read once: its bytes checked against ``sha256`` (a truth
    header's) when given, before anything in them is parsed; its arrays' declared sizes against
    the memory this process may use (:func:`glsim.io.npzfile.read_npz`) before they are made."""
    from glsim.io.npzfile import NpzError, read_npz
    from glsim.limits import memory_budget

    path = Path(path)
    again = "re-run the library command on its directory to write it"
    try:
        size = os.stat(path).st_size
        if size > memory_budget():
            raise TruthFileError(f"{path}: a geometry file of {size / 2**30:.3g} GiB, more than the "
                                 f"{memory_budget() / 2**30:.3g} GiB this process may use; {again}")
        with open(path, "rb") as f:
            data = f.read(size + 1)
    except OSError as exc:
        raise TruthFileError(f"{path}: cannot be read ({exc.strerror or exc}); check the path") from None
    if sha256 is not None and sha256_bytes(data) != sha256:
        raise TruthFileError(f"{path}: the geometry file fails the SHA-256 its truth file's header gives (not "
                             "the library's geometry, or damaged); run `glsim library DIR --verify`, then the "
                             "library command again to write it")
    try:
        arrays = read_npz(data, GEOMETRY_ARRAYS, ("patches",), check=_declared_problem, label=str(path))
    except NpzError as exc:
        raise TruthFileError(f"{exc}; not a readable glsim geometry file — {again}") from None
    a = {k: arrays[k] for k in GEOMETRY_ARRAYS}
    patches = arrays.get("patches")
    problem = _inconsistent(a, patches)
    if problem:
        raise TruthFileError(f"{path}: a damaged geometry file ({problem}); run `glsim library DIR --verify`, "
                             "then the library command again to write it")
    return Geometry(a["nodes"], a["quads"], tuple(int(s) for s in a["steps"]), a["displacements"],
                    a["element_labels"], patches)


def _declared_problem(members: dict) -> str:
    """:func:`_inconsistent` on the arrays' declared shapes and kinds, before they are read."""
    problem = _inconsistent({k: members[k] for k in GEOMETRY_ARRAYS}, members.get("patches"), indices=False)
    return f"a damaged geometry file ({problem})" if problem else ""


def _inconsistent(a: dict, patches, indices: bool = True) -> str:
    """What in a geometry file's arrays does not fit together ("" if nothing): their shapes,
    kinds and (``indices``) the node indices of the quads and patches (a patch's centre may be a
    derived-centre code, < 0)."""
    first = lambda x: x.shape[0] if x.shape else -1  # noqa: E731   (arrays, or npzfile.Member: shape and dtype)
    N, M, S = first(a["nodes"]), first(a["quads"]), first(a["steps"])
    shapes = {"nodes": (N, 3), "quads": (M, 4), "steps": (S,), "displacements": (S, N, 3), "element_labels": (M,)}
    if patches is not None:
        shapes["patches"] = (M, 9)
    arrays = {**a, "patches": patches}
    for name, shape in shapes.items():
        kind = "iu" if name in ("quads", "steps", "element_labels", "patches") else "f"
        if arrays[name].shape != shape or arrays[name].dtype.kind not in kind:
            return f"{name} is {arrays[name].dtype} {arrays[name].shape}, not {shape}"
    if not indices:
        return ""
    for name, idx in (("quads", a["quads"]), ("patches", None if patches is None else patches[:, :8])):
        if idx is not None and idx.size and (idx.min() < 0 or idx.max() >= N):
            return f"{name} refer to nodes {idx.min()}…{idx.max()} of {N}"
    return ""
