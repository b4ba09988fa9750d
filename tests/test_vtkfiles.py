"""Truth for ParaView (--truth-format vtk): the .vti holds every map at the pixel centres, read
back byte for byte with a reader written from VTK's XML file-format description; the FE mesh
series holds the mesh in camera 0's frame with each step's displacement."""
import re
import xml.etree.ElementTree as ET

import meshio
import numpy as np

from glsim.render import Renderer
from glsim.scene import Plate, Render, Scene, Specimen, bulge_scene
from glsim.scene.camera import to_camera
from glsim.workflows.sequence import write_sequence

VTK_TYPES = {"UInt8": np.uint8, "Int32": np.int32, "Float64": np.float64}


def read_vti(path):
    """{name: (H, W[, C]) array} from an ImageData file with raw appended data (UInt64 headers)."""
    raw = path.read_bytes()
    start = raw.index(b"<AppendedData")
    data = raw[raw.index(b"_", start) + 1:]
    root = ET.fromstring(raw[:start].decode() + "</VTKFile>")
    x0, x1, y0, y1, _, _ = map(int, root.find("ImageData").get("WholeExtent").split())
    W, H = x1 - x0 + 1, y1 - y0 + 1
    out = {}
    for a in root.iter("DataArray"):
        offset, n = int(a.get("offset")), int(a.get("NumberOfComponents"))
        size = int(np.frombuffer(data[offset:offset + 8], "<u8")[0])
        values = np.frombuffer(data[offset + 8:offset + 8 + size], VTK_TYPES[a.get("type")])
        out[a.get("Name")] = values.reshape((H, W, n) if n > 1 else (H, W))   # x (= u) runs fastest
    return out


def test_vtk_truth_and_mesh_series(tmp_path):
    scene = bulge_scene(size=(64, 48), steps=2).replace(render={"backend": "cpu"})
    w = write_sequence(scene, tmp_path, cameras=[1], truth=True, truth_format="vtk")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "cam1_0000.tif", "cam1_0000_truth.vti", "cam1_0001.tif", "cam1_0001_truth.vti", "cam1_0002.tif",
        "cam1_0002_truth.vti", "mesh.pvd", "mesh_0000.vtu", "mesh_0001.vtu", "mesh_0002.vtu", "render-manifest.jsonl",
        "scene.json"]
    assert len(w.truth) == 3
    with Renderer(scene) as r:
        truth = r.render(1, 2, truth=True).truth
        mesh = r.mesh
    back = read_vti(tmp_path / "cam1_0002_truth.vti")
    assert back["mask"].astype(bool).tolist() == truth.mask.tolist() and truth.mask.sum() > 500
    assert np.array_equal(back["element"], truth.element)
    for name, a in (("xi", truth.xi), ("eta", truth.eta), ("ref_u", truth.ref_uv[..., 0]),
                    ("X_undeformed", truth.X_undeformed), ("X_deformed", truth.X_deformed),
                    ("displacement", truth.X_deformed - truth.X_undeformed)):
        assert np.array_equal(back[name], a, equal_nan=True), name           # float64, NaN outside
    cam0 = scene.cameras[0]
    for k in range(3):
        m = meshio.read(tmp_path / f"mesh_{k:04d}.vtu")
        assert np.allclose(m.points, to_camera(mesh.nodes, cam0), rtol=0, atol=1e-12)
        u = to_camera(mesh.nodes + mesh.displacements[k], cam0) - to_camera(mesh.nodes, cam0)
        assert np.allclose(m.point_data["displacement"], u, rtol=0, atol=1e-12)
    pvd = (tmp_path / "mesh.pvd").read_text()
    assert re.findall(r'file="([^"]+)"', pvd) == ["mesh_0000.vtu", "mesh_0001.vtu", "mesh_0002.vtu"]


def _plate(n_steps):
    shifts = tuple((0.1 * k, 0.0, 0.0) for k in range(n_steps + 1))
    return Scene(cameras=bulge_scene(size=(32, 24)).cameras[:1], render=Render(backend="cpu"),
                 specimen=Specimen(plate=Plate(width=40, height=30, nx=2, ny=2, translations=shifts),
                                   t=(0.0, 0.0, 600.0)))


def test_force_removes_an_earlier_vtk_mesh_series(tmp_path):
    write_sequence(_plate(3), tmp_path, truth=True, truth_format="vtk")
    assert (tmp_path / "mesh_0003.vtu").exists()
    write_sequence(_plate(1), tmp_path, truth=True, truth_format="vtk", force=True)
    assert not (tmp_path / "mesh_0003.vtu").exists() and (tmp_path / "mesh_0001.vtu").exists()
