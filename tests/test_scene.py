"""The scene-file tier: every rejection names its key and the fix; poses, defaults, examples."""

import dataclasses
import importlib.util
import json
import math
import re
import textwrap
from pathlib import Path

import cv2
import meshio
import numpy as np
import pytest

from glsim.scene.camera import look_at, project, rodrigues, stereo_pose
from glsim.errors import SceneError
from glsim.io.fe import specimen_mesh
from glsim.scene import Bulge, Output, Render, Scene, Speckle, bulge_scene, demo_effects, load_scene
from glsim.scene.model import LATER_KEYS

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

CAM = """
[[cameras]]
size = [320, 240]
fx = 1800.0
fy = 1800.0
cx = 159.5
cy = 119.5
"""
STEREO = "{Tx = -100.0, Ty = 0.0, Tz = 10.0, Theta = 1.0, Phi = 15.0, Psi = -2.0}"


def write(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def load(tmp_path: Path, text: str) -> Scene:
    return load_scene(write(tmp_path, text))


def cam(**lines) -> str:
    """CAM with keys replaced (value None drops the key) or added, as TOML source."""
    keys = {k: v for k, _, v in (line.partition(" = ") for line in CAM.strip().splitlines()[1:])}
    keys.update(lines)
    return "[[cameras]]\n" + "".join(f"{k} = {v}\n" for k, v in keys.items() if v is not None)


def message(key: str, fix: str) -> str:
    """A regex for 'key: problem — …fix…'."""
    return rf"^{re.escape(key)}: .* — .*{re.escape(fix)}"


# (id, scene text, key named, a fragment of the fix)
REJECTED = [
    # unknown keys, with a suggestion where one is close
    ("top-level", "sed = 1\n" + CAM, "sed", "did you mean 'seed'?"),
    ("render", CAM + "[render]\nmdoe = 'q4'\n", "render.mdoe", "did you mean 'mode'?"),
    ("output", CAM + "[output]\ndir = 'x'\n", "output.dir", "allowed keys in output: directory"),
    ("speckle", CAM + "[speckle]\ndensityy = 0.4\n", "speckle.densityy", "did you mean 'density'?"),
    ("specimen", CAM + "[specimen]\nplates = {}\n", "specimen.plates", "did you mean 'plate'?"),
    ("specimen-R", CAM + "[specimen]\nbulge = {}\nt = [0, 0, 1]\n", "specimen.t", "pose"),
    ("bulge", CAM + "[specimen.bulge]\nradius_mm = 4.0\n", "specimen.bulge.radius_mm", "'radius'"),
    ("mesh", CAM + "[specimen.mesh]\npath = 'a.inp'\nunits = 'm'\n", "specimen.mesh.units", "'unit'"),
    ("camera", cam(focal="5.0"), "cameras[0].focal", "allowed keys in cameras[0]: name, size"),
    ("camera-R", cam(R="[[1, 0, 0], [0, 1, 0], [0, 0, 1]]"), "cameras[0].R", "pose"),
    ("pose", cam(pose="{rvecs = [0, 0, 0]}"), "cameras[0].pose.rvecs", "did you mean 'rvec'?"),
    ("distortion", cam(distortion="{k7 = 0.1}"), "cameras[0].distortion.k7",
     "allowed keys in cameras[0].distortion: k1, k2, p1, p2, k3, k4, k5, k6"),
    ("stereo", CAM + cam(pose="{stereo = {Tx = 0, Ty = 0, Tz = 0, Theta = 0, Phi = 0, Psi = 0, Tw = 1}}"),
     "cameras[1].pose.stereo.Tw", "allowed keys in cameras[1].pose.stereo: Tx, Ty, Tz, Theta"),
    ("look_at", cam(pose="{look_at = {eye = [0, 0, 0], at = [0, 0, 1]}}"), "cameras[0].pose.look_at.at",
     "allowed keys"),
    # wrong types
    ("fx-string", cam(fx='"1800"'), "cameras[0].fx", "write e.g. 1.0"),
    ("fx-bool", cam(fx="true"), "cameras[0].fx", "write e.g. 1.0"),
    ("fy-list", cam(fy="[1800.0]"), "cameras[0].fy", "write e.g. 1.0"),
    ("fx-inf", cam(fx="inf"), "cameras[0].fx", "finite"),
    ("size-float", cam(size="[320.0, 240]"), "cameras[0].size", "sensor size in pixels"),
    ("size-scalar", cam(size="320"), "cameras[0].size", "write e.g. [1, 2, 3]"),
    ("name-number", cam(name="3"), "cameras[0].name", "in quotes"),
    ("bit_depth-float", cam(bit_depth="8.0"), "cameras[0].bit_depth", "write e.g. 4"),
    ("k1-string", cam(distortion="{k1 = 'a'}"), "cameras[0].distortion.k1", "write e.g. 1.0"),
    ("distortion-number", cam(distortion="0.1"), "cameras[0].distortion", "table"),
    ("pose-list", cam(pose="[0, 0, 0]"), "cameras[0].pose", "table"),
    ("t-short", cam(pose="{t = [0, 0]}"), "cameras[0].pose.t", "exactly 3 entries"),
    ("rvec-string", cam(pose="{rvec = [0, 'a', 0]}"), "cameras[0].pose.rvec[1]", "write e.g. 1.0"),
    ("R-shape", cam(pose="{R = [[1, 0], [0, 1]]}"), "cameras[0].pose.R", "exactly 3 entries"),
    ("spp-float", CAM + "[render]\nsamples_per_pixel = 4.0\n", "render.samples_per_pixel", "write e.g. 4"),
    ("mode-int", CAM + "[render]\nmode = 3\n", "render.mode", "in quotes"),
    ("background-bool", CAM + "[render]\nbackground = false\n", "render.background", "write e.g. 1.0"),
    ("seed-string", "seed = 'x'\n" + CAM, "seed", "write e.g. 4"),
    ("render-string", "render = 'gl'\n" + CAM, "render", "table"),
    ("specimen-string", "specimen = 'bulge'\n" + CAM, "specimen", "table"),
    ("translations-flat", CAM + "[specimen.plate]\ntranslations = [1, 2, 3]\n",
     "specimen.plate.translations[0]", "write e.g. [1, 2, 3]"),
    ("csv-number", CAM + "[specimen.mesh]\npath = 'a.inp'\ncsv = [1]\n", "specimen.mesh.csv[0]", "in quotes"),
    ("cameras-table", "[cameras]\nfx = 1.0\n", "cameras", "add [[cameras]]"),
    ("cameras-none", "seed = 1\n", "cameras", "add [[cameras]]"),
    # missing camera keys
    ("no-fx", cam(fx=None), "cameras[0].fx", "add fx to cameras[0]"),
    ("no-size", cam(size=None), "cameras[0].size", "add size to cameras[0]"),
    ("no-cx-cy", cam(cx=None, cy=None), "cameras[0].cx", "add cx, cy to cameras[0]"),
    ("speckle-camera", CAM + "[speckle.camera]\nsize = [10, 10]\nfy = 1.0\ncx = 0.0\ncy = 0.0\n",
     "speckle.camera.fx", "add fx to speckle.camera"),
    # impossible values
    ("fx-negative", cam(fx="-1800.0"), "cameras[0].fx", "focal length in pixels"),
    ("size-zero", cam(size="[0, 240]"), "cameras[0].size", "sensor size in pixels"),
    ("bit_depth-9", cam(bit_depth="9"), "cameras[0].bit_depth", "bits per pixel"),
    ("R-not-orthonormal", cam(pose="{R = [[1, 0, 0], [0, 2, 0], [0, 0, 1]]}"), "cameras[0].pose.R",
     "proper rotation matrix"),
    ("R-mirror", cam(pose="{R = [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}"), "cameras[0].pose.R", "rotation"),
    ("R-and-rvec", cam(pose="{R = [[1, 0, 0], [0, 1, 0], [0, 0, 1]], rvec = [0, 0, 0]}"),
     "cameras[0].pose.rvec", "either as R or as rvec"),
    ("stereo-first", cam(pose=f"{{stereo = {STEREO}}}"), "cameras[0].pose.stereo", "give the first camera"),
    ("stereo-no-Psi", CAM + cam(pose="{stereo = {Tx = 0, Ty = 0, Tz = 0, Theta = 0, Phi = 0}}"),
     "cameras[1].pose.stereo.Psi", "add Psi to cameras[1].pose.stereo"),
    ("stereo-and-t", CAM + cam(pose=f"{{stereo = {STEREO}, t = [0, 0, 1]}}"), "cameras[1].pose.stereo",
     "remove the other keys"),
    ("look_at-degenerate", cam(pose="{look_at = {eye = [0, 0, 5], target = [0, 0, 5]}}"),
     "cameras[0].pose.look_at.target", "away from its target"),
    ("look_at-up", cam(pose="{look_at = {eye = [0, 0, -5], up = [0, 0, 1]}}"), "cameras[0].pose.look_at.up",
     "not along the line"),
    ("look_at-no-eye", cam(pose="{look_at = {target = [0, 0, 5]}}"), "cameras[0].pose.look_at.eye",
     "add eye"),
    ("specimen-R-bad", CAM + "[specimen]\nbulge = {}\npose = {R = [[2, 0, 0], [0, 1, 0], [0, 0, 1]]}\n",
     "specimen.pose.R", "rotation"),
    ("specimen-stereo", CAM + f"[specimen]\nbulge = {{}}\npose = {{stereo = {STEREO}}}\n",
     "specimen.pose.stereo", "place the specimen with R or rvec"),
    ("top-level-late", CAM + "seed = 1\n", "cameras[0].seed", "must come before the first [table]"),
    ("duplicate-names", cam(name='"a"') + cam(name='"a"'), "cameras[1].name", "unique name"),
    ("mode", CAM + "[render]\nmode = 'q8'\n", "render.mode", "use one of fast, q4, exact"),
    ("interpolation", CAM + "[render]\ninterpolation = 'nearest'\n", "render.interpolation", "bspline3"),
    ("backend", CAM + "[render]\nbackend = 'vulkan'\n", "render.backend", "use one of gl, cpu"),
    ("precision", CAM + "[render]\nprecision = 'fp16'\n", "render.precision", "use one of fp32, fp64"),
    ("subsamples", CAM + "[render]\nsubsamples = 'jacobian'\n", "render.subsamples", "use one of mapped, newton"),
    ("spp-3", CAM + "[render]\nsamples_per_pixel = 3\n", "render.samples_per_pixel", "use 1, 4, 9, 16"),
    ("background", CAM + "[render]\nbackground = 1.5\n", "render.background", "fraction of full scale"),
    ("format", CAM + "[output]\nformat = 'jpg'\n", "output.format", "use 'tiff'"),
    ("pattern", CAM + "[output]\npattern = '{camera}_{frame}.{ext}'\n", "output.pattern",
     "{camera}, {step} and {ext}"),
    ("pattern-no-step", CAM + "[output]\npattern = '{camera}.{ext}'\n", "output.pattern",
     "include both {camera} and {step}"),
    ("specimen-none", CAM + "[specimen]\npose = {t = [0, 0, 300]}\n", "specimen", "keep one of"),
    ("specimen-two", CAM + "[specimen.bulge]\n[specimen.plate]\n", "specimen", "keep one of"),
    ("bulge-radius", CAM + "[specimen.bulge]\nradius = -1.0\n", "specimen.bulge.radius", "give it in mm"),
    ("plate-nx", CAM + "[specimen.plate]\nnx = 0\n", "specimen.plate.nx", "number of elements"),
    ("mesh-unit", CAM + "[specimen.mesh]\npath = 'a.inp'\nunit = 'inch'\n", "specimen.mesh.unit",
     "use one of mm, m"),
    ("mesh-no-path", CAM + "[specimen.mesh]\nunit = 'm'\n", "specimen.mesh.path", "FE mesh file"),
    ("mesh-two-steps", CAM + "[specimen.mesh]\npath = 'a.inp'\ncsv = ['u.csv']\npoint_data = ['U']\n",
     "specimen.mesh.csv", "keep one of point_data, files, csv"),
    ("mesh-field", CAM + "[specimen.mesh]\npath = 'a.inp'\nfield = 'U'\n", "specimen.mesh.field", "files"),
    ("speckle-density", CAM + "[speckle]\ndensity = 1.5\n", "speckle.density", "covered area"),
    ("image-no-scale", CAM + "[speckle]\nimage = 'ref.png'\n", "speckle.mm_per_px",
     "give the image scale in mm per pixel, or a speckle.camera table"),
    ("speckle-centre-generated", CAM + "[speckle]\ncentre = [1.0, 2.0]\n", "speckle.centre",
     "remove centre, or give an image"),
    ("speckle-centre-4", CAM + "[speckle]\nimage = 'ref.png'\nmm_per_px = 0.1\ncentre = [1.0, 2.0, 3.0, 4.0]\n",
     "speckle.centre", "[X, Y] or [X, Y, Z]"),
    ("speckle-u-along-normal", CAM + "[speckle]\nu_axis = [0.0, 0.0, 2.0]\n", "speckle.u_axis",
     "in-plane direction of the image's u axis"),
    ("speckle-normal-zero", CAM + "[speckle]\nnormal = [0.0, 0.0, 0.0]\n", "speckle.normal",
     "give a direction in the specimen's frame"),
    ("speckle-camera-and-axis", CAM + "[speckle]\nu_axis = [0.0, 1.0, 0.0]\n[speckle.camera]\nsize = [10, 10]\n"
     "fx = 1.0\nfy = 1.0\ncx = 0.0\ncy = 0.0\n", "speckle.u_axis", "remove it, or remove speckle.camera"),
]


@pytest.mark.parametrize("text, key, fix", [c[1:] for c in REJECTED], ids=[c[0] for c in REJECTED])
def test_rejected(tmp_path, text, key, fix):
    with pytest.raises(SceneError, match=message(key, fix)) as info:
        load(tmp_path, text)
    assert info.value.key == key


def test_missing_files_are_named(tmp_path):
    for table, key, name in (("[specimen.mesh]\npath = 'nope.inp'\n", "specimen.mesh.path", "nope.inp"),
                             ("[speckle]\nimage = 'ref.tif'\nmm_per_px = 0.05\n", "speckle.image", "ref.tif")):
        with pytest.raises(SceneError, match=message(key, "relative paths start at the scene file")) as info:
            load(tmp_path, CAM + table)
        assert str(tmp_path / name) in str(info.value)
    (tmp_path / "plate.inp").write_text("")
    with pytest.raises(SceneError, match=r"^specimen\.mesh\.csv\[1\]: file .*u2\.csv not found"):
        load(tmp_path, CAM + "[specimen.mesh]\npath = 'plate.inp'\ncsv = ['plate.inp', 'u2.csv']\n")


def test_unsupported_element_type(tmp_path):
    points = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 2], [2, 0, 2], [0, 2, 2]], float)
    meshio.write(tmp_path / "wedge.inp", meshio.Mesh(points, [("wedge", np.arange(6)[None])]))
    scene = load(tmp_path, CAM + "[specimen.mesh]\npath = 'wedge.inp'\n[specimen.pose]\nt = [0, 0, 300]\n")
    with pytest.raises(SceneError, match=re.escape(str(tmp_path / "wedge.inp")) + ".*'wedge' is not supported"
                       " — use quad/triangle shells"):
        specimen_mesh(scene)


def test_bad_files(tmp_path):
    path = write(tmp_path, CAM + "[render\nmode = 'q4'\n")
    with pytest.raises(SceneError, match=rf"^{re.escape(str(path))}: is not a valid TOML file .*line 8"):
        load_scene(path)
    with pytest.raises(SceneError, match=r"missing\.toml: scene file not found — check the path"):
        load_scene(tmp_path / "missing.toml")


# --------------------------------------------------------------------------------------------
# Accepted scenes


def test_stereo_scene(tmp_path):
    scene = load(tmp_path, f"""
        seed = 3
        [[cameras]]
        name = "left"
        size = [1624, 1234]
        fx = 6818.0
        fy = 6820.0
        cx = 811.5
        cy = 616.5
        skew = 0.5
        bit_depth = 12
        distortion = {{k1 = -0.05, p2 = 1e-4}}
        pose = {{rvec = [0.01, -0.02, 0.03], t = [1.0, -2.0, 3.0]}}
        [[cameras]]
        name = "right"
        size = [1624, 1234]
        fx = 6818.0
        fy = 6818.0
        cx = 811.5
        cy = 616.5
        pose = {{stereo = {STEREO}}}
        [specimen.plate]
        translations = [[0.1, 0, 0]]
        [specimen.pose]
        R = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
        t = [0, 0, 600]
        """)
    left, right = scene.cameras
    assert (left.name, left.bit_depth, left.skew, left.fy, scene.seed) == ("left", 12, 0.5, 6820.0, 3)
    assert (left.distortion.k1, left.distortion.p2, left.distortion.k3) == (-0.05, 1e-4, 0.0)
    np.testing.assert_allclose(left.rotation, rodrigues([0.01, -0.02, 0.03]), atol=1e-15)
    R2, t2 = stereo_pose(left.rotation, left.translation, -100.0, 0.0, 10.0, 1.0, 15.0, -2.0)
    np.testing.assert_allclose(right.rotation, R2, atol=1e-15)
    np.testing.assert_allclose(right.translation, t2, atol=1e-12)
    assert scene.specimen.R == ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    assert scene.specimen.t == (0.0, 0.0, 600.0) and scene.specimen.plate.translations == ((0.1, 0.0, 0.0),)
    assert scene.base_dir == str(tmp_path.resolve())


def test_poses(tmp_path):
    rvec = [0.3, -0.2, 0.1]
    scene = load(tmp_path, cam(pose=f"{{rvec = {rvec}, t = [5, 6, 7]}}")
                 + cam(pose="{look_at = {eye = [300, 10, 80], target = [0, 0, 600], up = [0, -1, 0.1]}}")
                 + cam(pose="{R = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]}") + cam())
    np.testing.assert_allclose(scene.cameras[0].rotation, cv2.Rodrigues(np.array(rvec))[0], atol=1e-15)
    assert scene.cameras[0].t == (5.0, 6.0, 7.0)
    R, t = look_at([300, 10, 80], [0, 0, 600], [0, -1, 0.1])
    np.testing.assert_allclose(scene.cameras[1].rotation, R, atol=1e-15)
    np.testing.assert_allclose(scene.cameras[1].translation, t, atol=1e-12)
    assert scene.cameras[2].R == ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (-1.0, 0.0, 0.0))
    assert scene.cameras[3].R == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    assert [c.name for c in scene.cameras] == ["cam0", "cam1", "cam2", "cam3"]


def test_minimal_scene_defaults_and_json(tmp_path):
    scene = load(tmp_path, CAM)
    assert scene.specimen.bulge == Bulge() and scene.render == Render() and scene.output == Output()
    data = json.loads(scene.to_json())
    assert data == scene.to_dict()
    later = LATER_KEYS["render"]            # keys added since the first release, left out at their default
    assert data["render"] == {k: v for k, v in dataclasses.asdict(Render()).items() if k not in later}
    assert all(getattr(Render(), k) == v for k, v in later.items())
    assert data["output"] == dataclasses.asdict(Output())
    assert data["speckle"] == {**json.loads(json.dumps(dataclasses.asdict(Speckle()))), "camera": None}
    assert data["specimen"]["bulge"] == dataclasses.asdict(Bulge())
    assert data["specimen"]["R"] == np.eye(3).tolist() and data["specimen"]["t"] == [0, 0, 0]
    camera = data["cameras"][0]
    assert camera["distortion"] == {k: 0.0 for k in camera["distortion"]} and len(camera["distortion"]) == 12
    assert (camera["name"], camera["size"], camera["skew"], camera["bit_depth"]) == ("cam0", [320, 240], 0.0, 8)
    assert {"seed", "base_dir"} <= set(data)


def test_replace():
    scene = bulge_scene(size=(160, 120), steps=1)
    q4 = scene.replace(render={"mode": "q4"}, seed=5)
    assert (q4.render.mode, q4.seed, q4.render.interpolation) == ("q4", 5, scene.render.interpolation)
    assert scene.render.mode == "exact" and q4.cameras == scene.cameras
    with pytest.raises(SceneError, match=message("render.mdoe", "allowed keys in render: backend, mode")):
        scene.replace(render={"mdoe": "q4"})
    with pytest.raises(SceneError, match=message("render.mode", "use one of fast, q4, exact")):
        scene.replace(render={"mode": "q5"})


def test_bulge_scene_geometry():
    scene = bulge_scene()
    t = np.array(scene.specimen.t)
    for cam in scene.cameras:
        uv, ok = project(t, cam)
        assert ok and np.all(np.abs(uv - (np.array(cam.size) - 1) / 2) <= 0.05 * np.array(cam.size))
    axes = [cam.rotation[2] for cam in scene.cameras]  # optical axes in the world frame
    assert math.degrees(math.acos(np.dot(*axes))) == pytest.approx(30.0, abs=0.01)
    normal = -np.array(scene.specimen.R)[:, 2]
    views = [(cam.center - t) / np.linalg.norm(cam.center - t) for cam in scene.cameras]
    bisector = (views[0] + views[1]) / np.linalg.norm(views[0] + views[1])
    np.testing.assert_allclose(normal, bisector, atol=1e-12)
    assert np.dot(normal, views[0]) == pytest.approx(np.dot(normal, views[1]), abs=1e-12)


# --------------------------------------------------------------------------------------------
# examples/


def _is_spec(path) -> bool:
    """A library, training or design spec names its base scene (scene = "…" or [scene]); a scene never does."""
    import tomllib
    return "scene" in tomllib.loads(path.read_text())


@pytest.mark.parametrize("path", sorted(p for p in EXAMPLES.glob("**/*.toml") if not _is_spec(p)),
                         ids=lambda p: str(p.relative_to(EXAMPLES)))
def test_examples_load(path):
    """Every example scene loads (the specs: test_example_specs_are_checked below)."""
    scene = load_scene(path)
    mesh = specimen_mesh(scene)
    assert mesh.n_steps >= 2 and scene.base_dir == str(path.parent)


@pytest.mark.parametrize("path", sorted(p for p in EXAMPLES.glob("**/*.toml") if _is_spec(p)),
                         ids=lambda p: str(p.relative_to(EXAMPLES)))
def test_example_specs_are_checked(path):
    """Every example spec is a spec: a design spec checked whole as glsim design reads it (nothing
    rendered); a library or training spec read with its base scene (their expansion is tested in
    tests/test_library.py and tests/test_training_library.py)."""
    import tomllib
    data = tomllib.loads(path.read_text())
    if "engine" in data or "dic" in data:
        from glsim.workflows.design.spec import load_design
        design = load_design(path)
        assert design.plan.variants and design.settings
    else:
        from glsim.workflows.library.spec import read_spec
        spec, spec_dir = read_spec(path)
        assert "scene" in spec and spec_dir == path.parent


def test_bulge_example_is_bulge_scene():
    scene, built_in = load_scene(EXAMPLES / "bulge.toml"), bulge_scene()
    for cam, ref in zip(scene.cameras, built_in.cameras, strict=True):
        np.testing.assert_allclose(cam.rotation, ref.rotation, atol=1e-6)
        np.testing.assert_allclose(cam.translation, ref.translation, atol=1e-6)
        assert dataclasses.replace(cam, R=ref.R, t=ref.t) == ref
    np.testing.assert_allclose(scene.specimen.R, built_in.specimen.R, atol=1e-12)
    assert dataclasses.replace(scene, cameras=built_in.cameras, base_dir=".",
                               specimen=dataclasses.replace(scene.specimen, R=built_in.specimen.R)) == built_in


def test_plate_shift_example_renders():
    from glsim.render import render

    scene = load_scene(EXAMPLES / "plate_shift.toml")
    truth = render(scene, step=2, backend="cpu", truth=True).truth
    assert truth.mask.mean() > 0.5
    shift = truth.X_deformed[truth.mask] - truth.X_undeformed[truth.mask]
    np.testing.assert_allclose(shift, np.broadcast_to([0.25, -0.1, 0.0], shift.shape), atol=1e-9)


def test_plate_inp_files_are_reproducible(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("make_plate_inp", EXAMPLES / "make_plate_inp.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "OUT", tmp_path)
    module.main()
    for name in ("plate.inp", "u_step1.csv", "u_step2.csv"):
        assert (tmp_path / name).read_text() == (EXAMPLES / "plate_inp" / name).read_text()
    mesh = specimen_mesh(load_scene(EXAMPLES / "plate_inp" / "scene.toml"))
    assert mesh.n_elements == 48 and mesh.node_labels[0] == 101 and mesh.element_labels[0] == 1001
    x = mesh.nodes[:, 0]
    np.testing.assert_allclose(mesh.displacements[2][:, 0], 0.004 * x, atol=1e-12)


def _example_module(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_c3d20r_hole_example_renders_end_to_end(tmp_path, monkeypatch, gl_ctx):
    """The Abaqus C3D20R open-hole plate: the committed files are what its script writes; the
    scene reads 100 quadratic bricks (their outer faces as curved Q8 patches) and renders
    camera 0 at the last load step, whose truth displacement on the face it sees is the Kirsch
    field the script prescribed at the nodes, within what quadratic interpolation of it
    between nodes leaves (2 % of its largest value)."""
    from glsim.errors import RenderWarning
    from glsim.render import Renderer
    module = _example_module("make_hole_c3d20r")
    monkeypatch.setattr(module, "OUT", tmp_path)
    module.main()
    for name in ("plate.inp", "u_step1.csv", "u_step2.csv"):
        assert (tmp_path / name).read_text() == (EXAMPLES / "hole_c3d20r" / name).read_text()
    scene = load_scene(EXAMPLES / "hole_c3d20r" / "scene.toml")
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        assert r.mesh.is_quadratic and set(r.mesh.element_labels.tolist()) == set(range(1, 101))
        with pytest.warns(RenderWarning, match="grazing"):   # the plate's 2 mm sides and the hole's wall
            truth = r.render(0, 2, truth=True).truth
    front = truth.mask.copy()
    Xu = truth.X_undeformed
    R, t = np.asarray(scene.specimen.R), np.asarray(scene.specimen.t)
    local = (Xu - t) @ R                              # back to the plate's own frame (mm)
    front &= np.abs(local[..., 2] + module.THICK / 2) < 1e-9   # the face at z = −1 faces the cameras
    assert front.sum() > 0.5 * truth.mask.sum()
    want = module.kirsch(local[front][:, 0], local[front][:, 1], local[front][:, 2], module.STRESSES[1]) @ R.T
    got = truth.X_deformed[front] - Xu[front]
    assert np.abs(got - want).max() < 0.02 * np.abs(want).max()


def test_bulge_effects_example_is_demo_effects():
    scene, built_in = load_scene(EXAMPLES / "bulge_effects.toml"), demo_effects(bulge_scene())
    assert scene.lighting == built_in.lighting and scene.noise == built_in.noise
    assert dataclasses.replace(scene.optics, pixel_pitch=built_in.optics.pixel_pitch) == built_in.optics
    assert scene.optics.pixel_pitch == pytest.approx(built_in.optics.pixel_pitch, rel=1e-15)


@pytest.mark.parametrize("text,key,fix", [
    ("[lighting]\nambiant = 0.1\n", "lighting.ambiant", "did you mean 'ambient'"),
    ("[lighting]\ncombine = \"screen\"\n", "lighting.combine", "additive, multiplicative"),
    ("[[lighting.lights]]\nposition = [0, 0, 0]\ncutoff = 200.0\n", "lighting.lights[0].cutoff", "half-angle"),
    ("[[lighting.lights]]\nintensity = 0.2\n", "lighting.lights[0].position", "add position"),
    ("[optics]\nfocal_length = 30.0\nf_number = 2.0\nfocus_distance = 20.0\npixel_pitch = 0.004\n",
     "optics.focus_distance", "focused distance"),
    ("[optics]\nfocal_length = 30.0\nf_number = 2.0\nfocus_distance = 600.0\n", "optics.pixel_pitch",
     "add pixel_pitch"),
    ("[noise]\nmodel = \"salt\"\n", "noise.model", "gaussian, heteroscedastic, poisson_gaussian"),
    ("[noise]\nmodel = \"heteroscedastic\"\n", "noise.variance_file", "grey level;variance"),
    ("[noise]\nmodel = \"heteroscedastic\"\nvariance_file = \"nope.csv\"\n", "noise.variance_file", "check the path"),
])
def test_effect_tables_reject_bad_values(tmp_path, text, key, fix):
    with pytest.raises(SceneError, match=re.escape(key) + ".*" + re.escape(fix)):
        load(tmp_path, CAM + text)
