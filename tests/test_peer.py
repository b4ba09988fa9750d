"""glsim bench peer: a reduced run end to end; structure and accuracy figures with a meaning of
their own (the CPU oracle's float64 mapping), never timings. riley-raster is in the bench extra,
not the test extra: without it the glsim rows, the oracle comparison and the report still run."""
import importlib.util
import json
import math

import pytest

from glsim.bench import cli, peer
from glsim.check import closed_forms
from tools.docs import regions

pytestmark = [pytest.mark.workflow, pytest.mark.tools]   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

SIZE = ("203", "154")
RILEY = importlib.util.find_spec("riley") is not None


@pytest.mark.slow
@pytest.mark.gl
def test_reduced_peer_bench(tmp_path, capsys):
    assert cli.main(["peer", "--size", *SIZE, "--reps", "1", "--out", str(cli.RESULTS)]) == 2  # reduced: refused
    assert cli.main(["peer", "--size", *SIZE, "--reps", "1", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "peer.json").read_text())
    text = (tmp_path / "peer.md").read_text()
    assert text in capsys.readouterr().out and text.startswith("# glsim peer benchmark")
    rows = {(r["renderer"].split()[0] if r["renderer"].startswith("riley") else r["renderer"], r["k1"]): r
            for r in report["rows"]}
    modes = ("fast fp32", "q4 fp64", "exact fp64", "exact fp32", "exact fp64 newton", "exact fp32 newton")
    assert {k for k in rows if k[0] != "riley-raster"} == {(f"glsim GL {m}", k1) for m in modes for k1 in peer.K1S}
    assert {rows["riley-raster", k1]["status"] for k1 in peer.K1S} == {"ok" if RILEY else "not installed"}
    W, H = map(int, SIZE)
    for r in (r for r in report["rows"] if r["status"] == "ok"):
        assert len(r["seconds_all"]) == 1 and all(math.isfinite(r[k]) for k in ("seconds", "map_max_px", "grey_max"))
        assert 0.6 < r["coverage"] < 0.8                              # the plate covers 70 % of the image
        assert r["only_here"] + r["only_oracle"] <= 1e-3 * W * H     # coverage as the oracle's
    for k1 in peer.K1S:
        exact = rows["glsim GL exact fp64", k1]
        # float64 ray/patch intersection against the float64 oracle: within float64's bound
        assert exact["map_max_px"] <= closed_forms.FLOAT64 and exact["grey_max"] < 0.01
        # sub-samples placed by Newton from the pixel centre: the oracle's image as closely
        assert rows["glsim GL exact fp64 newton", k1]["grey_max"] < 0.01
        assert rows["glsim GL fast fp32", k1]["map_max_px"] < 0.01  # float32 and straight pieces
    # without distortion a face-on plate projects affinely: q4's inverse mapping is exact there
    assert rows["glsim GL q4 fp64", 0.0]["map_max_px"] <= closed_forms.FLOAT64
    assert rows["glsim GL q4 fp64", -0.1]["map_max_px"] > 1e-6
    if RILEY:  # riley's ξ, η against the oracle (its element taken from the oracle's)
        assert rows["riley-raster", 0.0]["map_max_px"] < 1e-6 and rows["riley-raster", -0.1]["map_max_px"] < 1e-3
        assert rows["riley-raster", 0.0]["grey_max"] < 0.01    # its image against its texture at the oracle's points
    assert len(report["goals"]) == 3 and all((g["met"] is None) != RILEY for g in report["goals"])
    readme = regions.peer_rows(report)                               # the README region from the same file
    assert readme.count("| glsim GL ") == len(modes) * len(peer.K1S) and f"{W}×{H}" in readme
