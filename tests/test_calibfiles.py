"""Rig files for DIC packages (glsim.io.calibfiles, glsim rig export): every format round-trips to
float precision, and OpenCV, given the parameters read back, projects 3-D points onto the pixels
glsim's own camera model gives (itself checked against cv2.projectPoints in test_camera.py)."""
import numpy as np
import pytest

from glsim.cli import main as glsim
from glsim.errors import SceneError
from glsim.io.calibfiles import FORMATS, export_rig, import_rig, stereo_extrinsics
from glsim.scene import bulge_scene
from glsim.scene.camera import Camera, Distortion, project, rotation_xyz, stereo_pose

SIZE = (1624, 1234)


def _rig(distortion=Distortion(k1=-0.12, k2=0.05, p1=3e-4, p2=-2e-4, k3=0.01), skew=(0.4, -0.2)):
    """An asymmetric rig whose world frame is not camera 0's (so relative formats must convert)."""
    R0 = rotation_xyz(2.0, -3.0, 1.5)
    a = Camera("left", SIZE, 6818.5, 6815.25, 811.7, 617.3, skew=skew[0], distortion=distortion, R=R0, t=(5.0, -3.0, 12.0))
    R1, t1 = stereo_pose(R0, a.t, -305.2, 1.7, 82.4, -1.2, 29.6, 0.8)
    b = Camera("right", SIZE, 6790.0, 6792.5, 805.1, 620.9, skew=skew[1],
               distortion=Distortion(k1=-0.1, k2=0.03, p1=-1e-4, p2=2e-4, k3=-0.02), R=R1, t=t1)
    return a, b


def _points(cam: Camera, n=50, seed=0):
    rng = np.random.default_rng(seed)
    X_cam = np.column_stack([rng.uniform(-40, 40, n), rng.uniform(-30, 30, n), rng.uniform(560, 640, n)])
    return (X_cam - cam.translation) @ cam.rotation            # world points in front of camera 0


def _cv2_project(X, cam: Camera) -> np.ndarray:
    import cv2
    rvec, _ = cv2.Rodrigues(cam.rotation)
    uv, _ = cv2.projectPoints(X.reshape(-1, 1, 3), rvec, cam.translation, cam.K, cam.distortion.coeffs)
    return uv.reshape(-1, 2)


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_round_trip_and_opencv_reprojection(tmp_path, fmt):
    a, b = _rig()
    path = export_rig(tmp_path / f"rig{FORMATS[fmt]}", a, b)
    a2, b2 = import_rig(path, image_size=SIZE if fmt == "matchid" else None)
    for orig, back in ((a, a2), (b, b2)):
        assert back.size == SIZE
        assert np.allclose([back.fx, back.fy, back.cx, back.cy, back.skew],
                           [orig.fx, orig.fy, orig.cx, orig.cy, orig.skew], rtol=1e-15, atol=1e-12)
        assert np.allclose(back.distortion.coeffs, orig.distortion.coeffs, rtol=1e-15, atol=1e-17)
    R, T = stereo_extrinsics(a, b)
    R2, T2 = stereo_extrinsics(a2, b2)
    assert np.abs(R2 - R).max() < 1e-14 and np.abs(T2 - T).max() < 1e-11
    # cv2.projectPoints ignores K's skew, so the reprojection check uses a rig without it
    a, b = _rig(skew=(0.0, 0.0))
    a2, b2 = import_rig(export_rig(tmp_path / f"noskew{FORMATS[fmt]}", a, b), image_size=SIZE)
    X = _points(a)
    # relative formats read back with camera 0 as the world frame; DICe keeps the world poses
    X_back = X if fmt == "dice" else X @ a.rotation.T + a.translation
    for orig, back in ((a, a2), (b, b2)):
        uv, ok = project(X, orig)
        assert ok.all()
        err = np.abs(_cv2_project(X_back, back) - uv).max()
        assert err < 1e-6, (fmt, orig.name, err)


def test_full_model_needs_a_format_that_holds_it(tmp_path):
    a, b = _rig(Distortion(k1=-0.1, k4=0.02, s1=1e-4))
    for fmt in ("matchid", "pyvale"):
        path = tmp_path / f"rig{FORMATS[fmt]}"
        with pytest.raises(SceneError, match=r"cameras\.left\.distortion.*k4, s1.*opencv or dice"):
            export_rig(path, a, b)
        assert not path.exists()                                  # refused before anything is written
    for fmt in ("opencv", "dice"):
        a2, b2 = import_rig(export_rig(tmp_path / f"full{FORMATS[fmt]}", a, b))
        assert np.allclose(a2.distortion.coeffs, a.distortion.coeffs, rtol=1e-15)


def test_matchid_layout_and_conventions(tmp_path):
    a, b = _rig()
    lines = export_rig(tmp_path / "rig.caldat", a, b).read_text().splitlines()
    table = dict(line.split(";") for line in lines)
    assert list(table)[:10] == ["Cam0_Fx [pixels]", "Cam0_Fy [pixels]", "Cam0_Fs [pixels]", "Cam0_Kappa 1",
                                "Cam0_Kappa 2", "Cam0_Kappa 3", "Cam0_P1", "Cam0_P2", "Cam0_Cx [pixels]",
                                "Cam0_Cy [pixels]"]
    assert list(table)[-6:] == ["Tx [mm]", "Ty [mm]", "Tz [mm]", "Theta [deg]", "Phi [deg]", "Psi [deg]"]
    # the stereo_pose above: camera 1 = Rz(0.8°)·Ry(29.6°)·Rx(−1.2°)·camera 0 + (−305.2, 1.7, 82.4)
    assert [float(table[k]) for k in ("Theta [deg]", "Phi [deg]", "Psi [deg]")] == pytest.approx([-1.2, 29.6, 0.8])
    assert [float(table[k]) for k in ("Tx [mm]", "Ty [mm]", "Tz [mm]")] == pytest.approx([-305.2, 1.7, 82.4])
    assert float(table["Cam0_Kappa 3"]) == 0.01 and float(table["Cam0_P1"]) == 3e-4


def test_dice_layout(tmp_path):
    import xml.etree.ElementTree as ET
    a, b = _rig()
    root = ET.parse(export_rig(tmp_path / "rig.xml", a, b)).getroot()
    top = {p.get("name"): p.get("value") for p in root.findall("Parameter")}
    assert top == {"xml_file_format": "DICe_xml_camera_system_file", "system_type_3D": "GENERIC_SYSTEM"}
    cam1 = {p.get("name"): p.get("value") for p in root.find("ParameterList[@name='CAMERA 1']")}
    assert cam1["IMAGE_HEIGHT_WIDTH"] == "{ 1234, 1624 }" and cam1["LENS_DISTORTION_MODEL"] == "OPENCV_LENS_DISTORTION"
    assert float(cam1["FX"]) == 6790.0 and float(cam1["TZ"]) == b.t[2]


def test_bad_rig_files_are_named(tmp_path):
    with pytest.raises(SceneError, match="'.txt' names no calibration format"):
        import_rig(tmp_path / "rig.txt")
    bad = tmp_path / "rig.caldat"
    bad.write_text("Cam0_Fx [pixels];6800\n")
    with pytest.raises(SceneError, match="has no 'Cam0_Fs"):
        import_rig(bad, image_size=SIZE)
    with pytest.raises(SceneError, match="holds no image size"):
        import_rig(bad)
    (tmp_path / "x.xml").write_text("<ParameterList><Parameter name='a'")
    with pytest.raises(SceneError, match="is not valid XML"):
        import_rig(tmp_path / "x.xml")
    with pytest.raises(SceneError, match="'vic3d' is not a calibration format"):
        export_rig(tmp_path / "r.xml", *_rig(), fmt="vic3d")


def test_cli_exports_the_scene_rig_and_converts_between_formats(tmp_path, capsys):
    scene = bulge_scene(size=(101, 77), steps=1)
    (tmp_path / "scene.json").write_text(scene.to_json())
    assert glsim(["rig", "export", str(tmp_path / "scene.json"), "-o", str(tmp_path / "rig.caldat")]) == 0
    assert glsim(["rig", "export", str(tmp_path / "rig.caldat"), "--size", "101", "77", "--format", "dice",
                  "-o", str(tmp_path / "rig.xml")]) == 0
    a, b = import_rig(tmp_path / "rig.xml")
    R, T = stereo_extrinsics(*scene.cameras[:2])
    R2, T2 = stereo_extrinsics(a, b)
    assert np.abs(R2 - R).max() < 1e-14 and np.abs(T2 - T).max() < 1e-10 and a.size == (101, 77)
    assert glsim(["rig", "export", str(tmp_path / "rig.caldat"), "-o", str(tmp_path / "x.xml")]) == 2
    assert "holds no image size" in capsys.readouterr().err and not (tmp_path / "x.xml").exists()
