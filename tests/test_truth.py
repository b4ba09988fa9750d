"""Compact truth (glsim.io.truth): the lossless coder, full maps rebuilt from (element, ξ, η)
against the renderer's float64 maps, and ``at(points)`` against the maps and an analytic plate."""
from pathlib import Path

import numpy as np
import pytest

from glsim.io.hashes import sha256_bytes
from glsim.errors import GlsimError
from glsim.io import truth as T
from glsim.io import truthcodec as C
from glsim.io import geometryfile as G
from glsim.render import Renderer
from glsim.scene import Plate, Pose, Speckle, Stereo
from glsim.scene.camera import Distortion

from _plates import plate_scene


def _runs_case(rng, H=40, W=57):
    element = np.full((H, W), -1, np.int64)
    element[5:35, 3:50] = rng.integers(0, 4, (30, 47)) // 3     # short and long runs
    element[10:20, 10:40] = 7
    element[:, 56] = 2                                          # runs at the row ends
    xi = rng.uniform(-1, 1, (H, W))
    xi[10:20, 10:40] = np.linspace(-1, 1, 30)[None, :] * np.linspace(0.5, 1, 10)[:, None]
    return element, xi


def test_lossless_coder_round_trips_bit_for_bit():
    rng = np.random.default_rng(0)
    element, xi = _runs_case(rng)
    eta = xi[::-1, ::-1].copy()
    mask = element >= 0
    eta[mask.nonzero()[0][:3], mask.nonzero()[1][:3]] = [np.nan, np.inf, -0.0]    # any bits survive
    xi[mask.nonzero()[0][5], mask.nonzero()[1][5]] = 1e308
    idx, same1, same2 = C._runs(element)
    for v in (xi.ravel()[idx], eta.ravel()[idx], rng.integers(-2**63, 2**63 - 1, len(idx)).view(np.float64)):
        back = C.decode_local(C.encode_local(v, same1, same2), same1, same2)
        np.testing.assert_array_equal(back.view(np.int64), v.view(np.int64))
    # a file holds element-local coordinates only (finite, within ±LOCAL_BOUND), bit for bit
    xi, eta = np.clip(np.nan_to_num(xi), -1, 1), np.clip(np.nan_to_num(eta), -1, 1)
    eta[mask.nonzero()[0][0], mask.nonzero()[1][0]] = -0.0
    data = C.encode(element, xi, eta, {"mode": "exact", "step": 0, "geometry": "g.npz", "geometry_sha256": ""})
    t = T.CompactTruth(None, *_split(data))
    np.testing.assert_array_equal(t.element, element)
    np.testing.assert_array_equal(t.xi[mask].view(np.int64), xi[mask].view(np.int64))
    np.testing.assert_array_equal(t.eta[mask].view(np.int64), eta[mask].view(np.int64))
    assert np.isnan(t.xi[~mask]).all()
    empty = C.encode(np.full((3, 4), -1), np.zeros((3, 4)), np.zeros((3, 4)), {})
    assert not T.CompactTruth(None, *_split(empty)).mask.any()


def _split(data: bytes):
    import json
    import struct
    (n,) = struct.unpack("<Q", data[C.PREFIX - 8:C.PREFIX])
    return json.loads(data[C.PREFIX:C.PREFIX + n]), data[C.PREFIX + n:]


# two cameras, the second placed by a stereo pose, before a tilted 40×30 mm plate that moves at step 1
STEREO_PLATE = dict(size=(72, 56), fx=400.0, fy=410.0, cx=72 / 2 - 0.3, cy=56 / 2 + 0.2, name="cam0",
                    second={"name": "cam1", "pose": Pose(stereo=Stereo(Tx=-60.0, Ty=0.0, Tz=5.0, Theta=0.0, Phi=11.0,
                                                                       Psi=0.5))},
                    plate=Plate(width=40.0, height=30.0, nx=5, ny=4, translations=((0.3, -0.2, 1.5),)),
                    specimen_pose=Pose(rvec=(0.1, 0.25, 0.02), t=(0.5, -0.3, 300.0)),
                    speckle=Speckle(dot_diameter_px=3.0, seed=4), base_dir=str(Path(".").resolve()), backend="cpu",
                    mode="exact")


def _compact(tmp_path, r: Renderer, camera, step, dtype="float64", **opts):
    """Write the compact truth of one render (and its geometry); return it read back and the
    renderer's full truth."""
    res = r.render(camera, step, truth=True, **opts)
    m = r.mesh
    arrays = G.geometry_arrays(m.nodes, m.quads, {s: m.displacements[s] for s in range(m.n_steps)}, m.element_labels)
    g = G.geometry_bytes(arrays)
    (tmp_path / "g.npz").write_bytes(g)
    header = C.image_header(res.camera, r.scene.cameras[0], r.reference.camera, res.options.mode, step, "g.npz",
                            sha256_bytes(g))
    t = res.truth
    path = tmp_path / f"{camera}_{step}.truth"
    path.write_bytes(C.encode(t.element, t.xi, t.eta, header, dtype))
    return T.load(path), t, path


@pytest.mark.parametrize("mode", ["exact", "q4"])
def test_full_maps_from_compact_truth_equal_the_renderers_float64_maps(tmp_path, mode):
    scene = plate_scene(**{**STEREO_PLATE, "mode": mode}, distortion=Distortion(k1=-0.08, p1=1e-3))
    with Renderer(scene) as r:
        for cam, step in (("cam0", 1), ("cam1", 1), ("cam1", 0)):
            c, full, path = _compact(tmp_path, r, cam, step)
            maps = c.maps()
            assert full.mask.mean() > 0.3
            for name in ("mask", "element", "xi", "eta", "X_undeformed", "X_deformed"):
                np.testing.assert_array_equal(getattr(maps, name), getattr(full, name), err_msg=name)
            np.testing.assert_allclose(maps.ref_uv, full.ref_uv, atol=1e-9, rtol=0, equal_nan=True)
            npz = full.element.size * (8 * 2 + 8 * 2 + 8 * 2 + 8 * 3 * 2 + 1)
            assert path.stat().st_size < npz / 4


@pytest.mark.gl
def test_gl_compact_truth_matches_full_maps_and_float32_bound(tmp_path, gl_ctx):
    scene = plate_scene(**{**STEREO_PLATE, "backend": "gl", "size": (96, 72), "cx": 96 / 2 - 0.3,
                             "cy": 72 / 2 + 0.2})
    with Renderer(scene, ctx=gl_ctx) as r:
        c, full, _ = _compact(tmp_path, r, "cam1", 1)
        maps = c.maps()
        for name in ("element", "xi", "eta", "X_undeformed", "X_deformed"):
            np.testing.assert_array_equal(getattr(maps, name), getattr(full, name), err_msg=name)
        # GL's own ref_uv is float32 hi/lo; the rebuilt one is the float64 projection
        np.testing.assert_allclose(maps.ref_uv, full.ref_uv, atol=1e-4, rtol=0, equal_nan=True)
        c32, _, _ = _compact(tmp_path, r, "cam1", 1, dtype="float32")
        m = full.mask
        assert np.abs(c32.xi[m] - full.xi[m]).max() <= 2 ** -25
        d = np.linalg.norm(c32.maps().X_deformed[m] - full.X_deformed[m], axis=1).max()
        assert d < 1e-6        # mm: element half-size (4 mm) × 3e-8


def test_at_points_equals_the_maps_of_camera0_in_the_reference_state(tmp_path):
    scene = plate_scene(**STEREO_PLATE, distortion=Distortion(k1=-0.1, k2=0.05))
    with Renderer(scene) as r:
        c0, full0, _ = _compact(tmp_path, r, "cam0", 0)      # camera 0, reference state
        c1, full1, _ = _compact(tmp_path, r, "cam1", 1)      # another image of the library
    H, W = full0.mask.shape
    v, u = np.mgrid[0:H, 0:W]
    pts = np.column_stack([u.ravel(), v.ravel()]).astype(float)
    at = c1.at(pts)                                         # its step (1) by default
    assert at.step == 1
    valid = at.valid.reshape(H, W)
    # the same pixels are covered, the same material point found (to float64 rounding)
    np.testing.assert_array_equal(valid, full0.mask)
    np.testing.assert_allclose(at.X_undeformed.reshape(H, W, 3)[valid], full0.X_undeformed[valid], atol=1e-9, rtol=0)
    np.testing.assert_allclose(at.xi.reshape(H, W)[valid], full0.xi[valid], atol=1e-11, rtol=0)
    # its deformed position is that point moved by the load step's displacement
    g = c1.geometry
    q = g.quads[at.element[at.valid]]
    from glsim.scene.bilinear import bilinear
    from glsim.scene.camera import to_camera
    Xd = to_camera(bilinear(g.deformed(1)[q], at.xi[at.valid], at.eta[at.valid]), c1.camera0)
    np.testing.assert_array_equal(at.X_deformed[at.valid], Xd)
    assert np.isnan(at.X_undeformed[~at.valid]).all()


def test_at_points_on_an_analytic_plate(tmp_path):
    """Fronto-parallel plate at Z = 300 mm, rigidly translated: the material point under pixel
    (u, v) is the ray's intersection with the plane, its displacement the translation."""
    scene = plate_scene(**{**STEREO_PLATE, "specimen_pose": Pose(rvec=(0.1, 0.0, 0.02), t=(0.5, -0.3, 300.0))},
                        distortion=Distortion(k1=-0.05))
    scene = scene.replace(specimen={"R": ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)), "t": (0.0, 0.0, 300.0)})
    with Renderer(scene) as r:
        c, _, _ = _compact(tmp_path, r, "cam0", 1)
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(10, 60, 200), rng.uniform(8, 46, 200)])
    at = c.at(pts)
    assert at.valid.all()
    from glsim.scene.camera import pixel_to_normalized, undistort
    cam = scene.cameras[0]
    xn, _ = undistort(pixel_to_normalized(pts, cam.intrinsics), cam.distortion.coeffs)
    expect = np.column_stack([xn * 300.0, np.full(len(pts), 300.0)])
    np.testing.assert_allclose(at.X_undeformed, expect, atol=1e-10, rtol=0)
    np.testing.assert_allclose(at.displacement, np.broadcast_to([0.3, -0.2, 1.5], (200, 3)), atol=1e-10, rtol=0)
    far = c.at([[-500.0, -500.0]])
    assert not far.valid[0] and np.isnan(far.displacement).all()


def test_header_names_camera0_and_version1_files_are_refused_with_the_fix(tmp_path):
    """The header names camera 0 "camera0"; files of format version 1 (no checksum, camera 0
    then "camera1" in the oldest) are refused, telling the user to re-render."""
    import json
    import struct

    scene = plate_scene(**STEREO_PLATE)
    with Renderer(scene) as r:
        c, _, path = _compact(tmp_path, r, "cam1", 1)
    assert "camera0" in c.header and "camera1" not in c.header and c.camera0 == scene.cameras[0]
    data = path.read_bytes()
    (n,) = struct.unpack("<Q", data[C.PREFIX - 8:C.PREFIX])
    header = {**json.loads(data[C.PREFIX:C.PREFIX + n]), "version": 1}
    text = json.dumps(header, sort_keys=True).encode()
    (tmp_path / "old.truth").write_bytes(b"GLTRUTH1" + struct.pack("<Q", len(text)) + text + data[C.PREFIX + n:])
    with pytest.raises(GlsimError, match="format version 1 .*without a checksum.*re-render it.*--force"):
        T.load(tmp_path / "old.truth")


def test_render_truth_npz_loads_with_maps_and_at(tmp_path):
    """Issue 29: truth.load refused `glsim render --truth`'s *_truth.npz."""
    from glsim.workflows.sequence import write_sequence

    scene = plate_scene(**STEREO_PLATE, distortion=Distortion(k1=-0.05)).replace(
        output={"pattern": "imgs/{camera}_{step:04d}.{ext}"})
    write_sequence(scene, tmp_path / "r", truth=True)
    with Renderer(scene) as r:
        c, _, _ = _compact(tmp_path, r, "cam1", 1)
    t = T.load(tmp_path / "r" / "imgs" / "cam1_0001_truth.npz")
    assert isinstance(t, T.MapTruth) and t.step == 1 and t.size == c.size
    with np.load(tmp_path / "r" / "imgs" / "cam1_0001_truth.npz") as z:
        for name in T.Truth.FIELDS:
            np.testing.assert_array_equal(getattr(t.maps(), name), z[name], err_msg=name)
    np.testing.assert_array_equal(t.maps().X_deformed, c.maps().X_deformed)
    pts = np.random.default_rng(5).uniform([10, 8], [60, 46], (50, 2))
    for a, b in ((t.at(pts), c.at(pts)), (t.at(pts, step=0), c.at(pts, step=0))):
        assert a.step == b.step and a.valid.sum() > 40
        np.testing.assert_array_equal(a.valid, b.valid)
        np.testing.assert_array_equal(a.X_deformed, b.X_deformed)
    (tmp_path / "lone_truth.npz").write_bytes((tmp_path / "r" / "imgs" / "cam1_0001_truth.npz").read_bytes())
    with pytest.raises(GlsimError, match="no scene.json in its folder or above"):
        T.load(tmp_path / "lone_truth.npz").at(pts)


def test_damaged_files_are_named_with_the_fix(tmp_path):
    scene = plate_scene(**STEREO_PLATE)
    with Renderer(scene) as r:
        c, _, path = _compact(tmp_path, r, "cam0", 1)
    data = path.read_bytes()
    (tmp_path / "cut.truth").write_bytes(data[:-10])
    with pytest.raises(GlsimError, match="truncated.*re-render"):
        T.load(tmp_path / "cut.truth")
    (tmp_path / "other.truth").write_bytes(b"not a truth file at all")
    with pytest.raises(GlsimError, match="not a glsim compact truth file"):
        T.load(tmp_path / "other.truth")
    arrays = dict(np.load(tmp_path / "g.npz"))
    for name, bad in (("quads", arrays["quads"] + 1000), ("displacements", arrays["displacements"][:, :-1]),
                      ("patches", np.zeros((len(arrays["quads"]), 8), np.int64))):
        (tmp_path / "g.npz").write_bytes(G.geometry_bytes({**arrays, name: bad}))
        with pytest.raises(GlsimError, match="g.npz: the geometry file fails the SHA-256 its truth file's header gives"):
            T.load(path).maps()
        with pytest.raises(GlsimError, match=f"g.npz: .*a damaged geometry file \\({name} .*"):
            G.read_geometry(tmp_path / "g.npz")
    (tmp_path / "g.npz").unlink()
    with pytest.raises(GlsimError, match="geometry file .* is missing"):
        T.load(path).maps()
