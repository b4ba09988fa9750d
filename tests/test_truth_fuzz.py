"""Fuzzing the compact truth reader: a valid ``.truth`` file of a rendered plate, mutated by bit
flips, truncations, byte insertions and overwrites, must never load with other maps — each
mutant is refused by name (TruthFileError) or, had it kept its bytes' meaning, would load the
same maps. The test runs 2,000 mutants (fixed seed); ``GLSIM_TRUTH_FUZZ=10000 pytest
tests/test_truth_fuzz.py`` runs more."""
import os
from pathlib import Path

import numpy as np
import pytest

from glsim.errors import GlsimError
from glsim.io import geometryfile as G
from glsim.io import truth as T
from glsim.io import truthcodec as C
from glsim.io.hashes import sha256_bytes
from glsim.render import Renderer
from glsim.scene import Plate, Pose, Speckle

from _plates import plate_scene

MUTANTS = int(os.environ.get("GLSIM_TRUTH_FUZZ", "2000"))
MAPS = ("mask", "element", "xi", "eta", "ref_uv", "X_undeformed", "X_deformed")


@pytest.fixture(scope="module")
def original(tmp_path_factory):
    """A truth file of a tilted plate that moves at step 1 (CPU render, 48 × 36 px), its geometry
    beside it; (its bytes, its header, its maps)."""
    d = tmp_path_factory.mktemp("fuzz")
    scene = plate_scene(size=(48, 36), fx=300.0, plate=Plate(width=40.0, height=30.0, nx=5, ny=4,
                                                              translations=((0.3, -0.2, 1.5),)),
                        specimen_pose=Pose(rvec=(0.1, 0.25, 0.02), t=(0.5, -0.3, 300.0)),
                        speckle=Speckle(dot_diameter_px=3.0, seed=4), base_dir=str(Path(".").resolve()),
                        backend="cpu", mode="exact")
    with Renderer(scene) as r:
        res = r.render("c", 1, truth=True)
        m = r.mesh
        g = G.geometry_bytes(G.geometry_arrays(m.nodes, m.quads, {s: m.displacements[s] for s in range(m.n_steps)},
                                               m.element_labels))
        header = C.image_header(res.camera, scene.cameras[0], r.reference.camera, res.options.mode, 1, "g.npz",
                                sha256_bytes(g))
    (d / "g.npz").write_bytes(g)
    data = C.encode(res.truth.element, res.truth.xi, res.truth.eta, header)
    (d / "t.truth").write_bytes(data)
    t = T.read(d / "t.truth")
    maps = t.maps()
    assert maps.mask.mean() > 0.3
    return d, data, t.header, {name: getattr(maps, name) for name in MAPS}


def mutate(data: bytes, rng) -> bytes:
    """One random mutation: 1–8 bit flips, a truncation, 1–16 inserted bytes, or 1–16 bytes
    overwritten."""
    b = bytearray(data)
    kind = rng.integers(4)
    if kind == 0:
        for _ in range(rng.integers(1, 9)):
            i = rng.integers(len(b))
            b[i] ^= 1 << int(rng.integers(8))
    elif kind == 1:
        del b[rng.integers(len(b)):]
    elif kind == 2:
        i = rng.integers(len(b) + 1)
        b[i:i] = rng.integers(0, 256, rng.integers(1, 17), dtype=np.uint8).tobytes()
    else:
        i = rng.integers(len(b))
        b[i:i + 16] = rng.integers(0, 256, len(b[i:i + 16]), dtype=np.uint8).tobytes()
    return bytes(b)


def same_maps(maps, expected) -> bool:
    return all(np.array_equal(getattr(maps, name), expected[name], equal_nan=True) for name in MAPS)


def test_no_mutant_of_a_truth_file_loads_with_changed_maps(original):
    d, data, header, expected = original
    rng = np.random.default_rng(20240551)
    path = d / "mutant.truth"
    refused = unchanged = 0
    for k in range(MUTANTS):
        mutant = mutate(data, rng)
        if mutant == data:
            unchanged += 1
            continue
        path.write_bytes(mutant)
        try:
            t = T.read(path)
            maps = t.maps()
        except T.TruthFileError:
            refused += 1
            continue
        except GlsimError as exc:      # another glsim error would be a named refusal too, but none is expected
            pytest.fail(f"mutant {k}: refused as {type(exc).__name__}, not TruthFileError: {exc}")
        assert t.header == header and same_maps(maps, expected), f"mutant {k} loaded with changed maps"
    print(f"{MUTANTS} mutants: {refused} refused by name, {unchanged} unchanged, "
          f"{MUTANTS - refused - unchanged} loaded the same maps")
    assert refused + unchanged == MUTANTS       # a SHA-256 over every byte after it: all changed files refused
