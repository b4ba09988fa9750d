"""The generated speckle is a property of the specimen's surface in mm (issue 29): one plate
meshed as Q4, Q8, Q9, T3 or graded Q4, or reaching further outside camera 0's view, carries the
same dots at the same material points, so its images agree."""
from __future__ import annotations

import dataclasses
import pickle
from types import SimpleNamespace

import meshio
import numpy as np
import pytest

from glsim.io.fe import specimen_mesh
from glsim.render import Renderer
from glsim.scene import load_scene, speckle
from glsim.imaging.reference import camera_scale, make_reference, pattern_scale, placement

WIDTH, HEIGHT = 100.0, 50.0          # mm, the plate of the issue
NX, NY = 10, 5                       # its elements
EXTRA = 12.0                         # mm, the row of elements added at +X, outside camera 0's view


def plate(kind: str = "quad", graded: bool = False, extra: bool = False, nx: int = NX, ny: int = NY,
          jitter: float = 0.0):
    """The 100 × 50 mm plate (X 0…100, Y 0…50 in its own frame) as meshio points and cells:
    ``kind`` quad / quad8 / quad9 / triangle (each quad split in two); graded: node spacing
    growing towards +X and +Y; extra: one more column of elements EXTRA mm wide beyond X = 100;
    jitter: relative noise on the coordinates (float rounding of the extent)."""
    s = np.linspace(0.0, 1.0, nx + 1)
    xs = WIDTH * (s ** 1.7 if graded else s)
    if extra:
        xs = np.append(xs, WIDTH + EXTRA)
    s = np.linspace(0.0, 1.0, ny + 1)
    ys = HEIGHT * (s ** 1.5 if graded else s)
    quadratic = kind in ("quad8", "quad9")
    if quadratic:                     # mid-side nodes at the edge midpoints
        xs = np.sort(np.concatenate([xs, (xs[:-1] + xs[1:]) / 2]))
        ys = np.sort(np.concatenate([ys, (ys[:-1] + ys[1:]) / 2]))
    x, y = np.meshgrid(xs, ys)
    points = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    points[:, :2] *= 1 + jitter * np.random.default_rng(1).standard_normal((len(points), 2))
    at = np.arange(x.size).reshape(x.shape)
    if not quadratic:
        q = np.stack([at[:-1, :-1], at[:-1, 1:], at[1:, 1:], at[1:, :-1]], -1).reshape(-1, 4)
        if kind == "triangle":
            return points, [("triangle", np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))]
        return points, [("quad", q)]
    cells = []
    for r in range(0, x.shape[0] - 1, 2):
        for c in range(0, x.shape[1] - 1, 2):
            cell = [at[r, c], at[r, c + 2], at[r + 2, c + 2], at[r + 2, c],
                    at[r, c + 1], at[r + 1, c + 2], at[r + 2, c + 1], at[r + 1, c]]
            cells.append(cell + [at[r + 1, c + 1]] if kind == "quad9" else cell)
    used = np.unique(cells)            # a Q8 mesh has no centre nodes
    remap = np.full(len(points), -1)
    remap[used] = np.arange(len(used))
    return points[used], [(kind, remap[np.array(cells)])]


def scene_file(d, seed: int = 7, **mesh):
    """Camera 0 (400 × 300 px, 120,000 px) looks obliquely at the plate from about 250 mm; it
    sees X −3…93 mm, so the plate's +X end and the extra column lie outside its view."""
    d.mkdir(parents=True, exist_ok=True)
    points, cells = plate(**mesh)
    meshio.write(d / "plate.vtu", meshio.Mesh(points, cells))
    (d / "scene.toml").write_text(f"""[[cameras]]
size = [400, 300]
fx = 1000.0
fy = 1000.0
cx = 199.5
cy = 149.5

[specimen.mesh]
path = "plate.vtu"

[specimen.pose]
rvec = [0.15, -0.2, 0.05]
t = [-40.0, -25.0, 200.0]

[speckle]
seed = {seed}

[render]
backend = "cpu"
""")
    return load_scene(d / "scene.toml")


KINDS = {"Q4": {}, "Q8": {"kind": "quad8"}, "Q9": {"kind": "quad9"}, "T3": {"kind": "triangle"},
         "graded Q4": {"graded": True}, "finer Q4": {"nx": 2 * NX, "ny": 2 * NY}, "extra column": {"extra": True}}


def grey8(image):
    return np.rint(np.clip(image.astype(np.float64), 0, 1) * 255)


@pytest.fixture(scope="module")
def images(shared_dir):
    """Camera 0's image of every meshing of the plate (bspline3, the default, and procedural),
    each rendered once per run for every worker (the arrays the test reads, pickled; the workers
    render different meshings at once, then wait for the rest)."""
    def make(name):
        def render(d):
            with Renderer(scene_file(d, **KINDS[name]), "cpu") as r:
                res = r.render(0, 0, truth=True)
                out = (SimpleNamespace(image=res.image, truth=SimpleNamespace(
                    mask=res.truth.mask, X_undeformed=res.truth.X_undeformed)),
                    r.render(0, 0, interpolation="procedural").image)
            (d / "images.pickle").write_bytes(pickle.dumps(out))
        return render

    for i, name in enumerate(KINDS):
        shared_dir(f"speckle-plate{i}", make(name), wait=False)
    return {name: pickle.loads((shared_dir(f"speckle-plate{i}", make(name)) / "images.pickle").read_bytes())
            for i, name in enumerate(KINDS)}


@pytest.mark.parametrize("name", [k for k in KINDS if k != "Q4"])
def test_every_meshing_of_one_plate_gives_the_same_image(images, name):
    """Q8, Q9, T3, graded, finer and further-reaching meshes of the plate against Q4: the same
    speckle at the same material points, so the same image, in 8 bit to the grey level (measured:
    bit-identical float32 images on llvmpipe's CPU oracle, ref_uv within 5e-13 px). Before, every
    dot moved with the mesh's extent: up to 225 grey levels apart (the extra column, 86k px)."""
    (q4, q4_procedural), (other, procedural) = images["Q4"], images[name]
    assert np.array_equal(other.truth.mask, q4.truth.mask) and q4.truth.mask.mean() > 0.7
    m = q4.truth.mask
    assert np.abs(other.truth.X_undeformed[m] - q4.truth.X_undeformed[m]).max() < 1e-9
    assert np.abs(grey8(other.image) - grey8(q4.image)).max() <= 1
    assert np.abs(grey8(procedural) - grey8(q4_procedural)).max() <= 1
    assert np.abs(other.image.astype(np.float64) - q4.image).max() < 1e-6      # float rounding only
    assert np.abs(procedural.astype(np.float64) - q4_procedural).max() < 1e-6
    assert np.abs(grey8(q4.image) - grey8(q4_procedural)).std() < 8             # the same pattern


def material_dots(scene):
    """The generated dots' centres as points (X, Y) of the plate (its frame, mm), and radii (mm):
    each centre's reference-camera ray met with the plate's plane Z = 0."""
    mesh = specimen_mesh(scene)
    ref = make_reference(scene, mesh)
    cam = ref.camera
    R, t = np.asarray(scene.specimen.R), np.asarray(scene.specimen.t)
    xn = (ref.dots.centres - [cam.cx, cam.cy]) / [cam.fx, cam.fy]
    rays = np.column_stack([xn, np.ones(len(xn))]) @ cam.rotation @ R      # the specimen frame
    eye = (cam.center - t) @ R
    X = eye + rays * (-eye[2] / rays[:, 2])[:, None]
    assert np.abs(X[:, 2]).max() < 1e-9
    scale = abs(eye[2]) / cam.fx                       # mm per reference px on the plane it faces
    return X[:, :2], ref.dots.radii * scale, ref


def test_the_dots_stay_at_their_material_points(tmp_path):
    """Directly on the dot list: the same seed puts the same dots at the same material points
    after the mesh is refined (10 × 5 → 20 × 10 and 40 × 20 elements), regraded, turned into
    Q8 or its coordinates rounded differently (the plate's edges lie on the reference image's
    pixel lattice, where rounding used to add a row of pixels and move every dot); a mesh that reaches 12 mm further keeps every dot and only adds dots beyond."""
    base, r_base, ref = material_dots(scene_file(tmp_path / "base"))
    assert len(base) > 1000 and ref.dots.shape == ref.image.shape
    for i, kw in enumerate(({"nx": 2 * NX, "ny": 2 * NY}, {"nx": 4 * NX, "ny": 4 * NY}, {"graded": True},
                            {"kind": "quad8"}, {"jitter": 1e-14}, {"jitter": -1e-14})):
        X, r, _ = material_dots(scene_file(tmp_path / f"m{i}", **kw))
        assert len(X) == len(base)
        np.testing.assert_allclose(X, base, rtol=0, atol=1e-9)
        np.testing.assert_allclose(r, r_base, rtol=1e-9)
    X, r, _ = material_dots(scene_file(tmp_path / "extra", extra=True))
    d = np.linalg.norm(X[None] - base[:, None], axis=-1)
    nearest = d.argmin(axis=1)
    assert d.min(axis=1).max() < 1e-9                         # every dot is still there …
    np.testing.assert_allclose(r[nearest], r_base, rtol=1e-9)
    others = np.setdiff1d(np.arange(len(X)), nearest)
    assert len(others) > 50 and X[others, 0].min() > WIDTH - 5   # … and the new ones lie beyond


def test_the_seed_still_chooses_the_pattern(tmp_path):
    a, _, _ = material_dots(scene_file(tmp_path / "a"))
    b, _, _ = material_dots(scene_file(tmp_path / "b", seed=8))
    assert len(a) != len(b) or np.abs(a - b).max() > 1


def test_a_pattern_is_the_same_whichever_rectangle_asks_for_it():
    """speckle.draw_pattern: the dots of a small rectangle are the big rectangle's dots that
    reach it, at the same coordinates; cells far from the origin (negative too) work alike."""
    for lo, hi in (((-3.0, -7.0), (20.0, 11.0)), ((1e4, -2e4), (1e4 + 15.0, -2e4 + 9.0))):
        big = speckle.draw_pattern(np.subtract(lo, 40.0), np.add(hi, 25.0), 0.8, 0.5, seed=3, edge=0.2)
        small = speckle.draw_pattern(lo, hi, 0.8, 0.5, seed=3, edge=0.2)
        reach = speckle.pattern_reach(0.8, 0.2)
        near = np.all((big[0] >= np.subtract(lo, reach)) & (big[0] <= np.add(hi, reach)), axis=1)
        assert len(small[1]) > 100
        np.testing.assert_array_equal(small[0], big[0][near])
        np.testing.assert_array_equal(small[1], big[1][near])
    crop = speckle.generate((60, 80), 4, seed=2)
    np.testing.assert_array_equal(speckle.generate((100, 150), 4, seed=2)[:60, :80], crop)


def test_the_dot_size_does_not_follow_the_mesh_extent(tmp_path):
    """The generator's unit for dot_diameter_px, camera 0's mm per px, is taken where camera 0's
    optical axis meets the plate: the same bit for bit for the plate and the plate reaching
    further (whose bounding box centre, the old point, moved 6 mm), so the reference pixels are
    the same size; within 1 % of camera 0's scale at the plate's centre. An axis that misses
    the plate takes the nearest point of its bounding box."""
    scales = []
    for d, kw in (("a", {}), ("b", {"extra": True})):
        scene = scene_file(tmp_path / d, **kw)
        mesh = specimen_mesh(scene)
        R, t = np.asarray(scene.specimen.R), np.asarray(scene.specimen.t)
        pl = placement(scene, mesh)
        s = pattern_scale(scene.cameras[0], pl, (mesh.nodes - t) @ R, R, t)
        cam = make_reference(scene, mesh).camera
        eye = (cam.center - t) @ R
        assert abs(eye[2]) / cam.fx == pytest.approx(s / 2, rel=1e-12)   # oversample 2: half a camera-0 px
        scales.append(s)
    assert scales[0] == scales[1]
    cam0 = scene.cameras[0]
    assert scales[0] == pytest.approx(camera_scale(cam0, (R @ [WIDTH / 2, HEIGHT / 2, 0] + t)[None]), rel=0.01)
    away = dataclasses.replace(cam0, t=tuple(np.add(cam0.t, [200.0, 0.0, 0.0])))   # its axis meets Z = 0 at X < 0
    eye, axis = (away.center - t) @ R, away.rotation[2] @ R
    hit = eye - eye[2] / axis[2] * axis
    assert hit[0] < -100 and 0 < hit[1] < HEIGHT
    edge = camera_scale(away, (R @ [0.0, hit[1], 0.0] + t)[None])
    assert pattern_scale(away, pl, (mesh.nodes - t) @ R, R, t) == pytest.approx(edge, rel=1e-12)
