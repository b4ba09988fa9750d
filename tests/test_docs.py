"""README and docs figures are generated from bench/results (python -m tools.docs): the committed
text matches its results files, and a changed digit inside a generated region is caught."""
import re
import shutil
from pathlib import Path

from tools.docs import cli, regions

ROOT = Path(__file__).resolve().parents[1]


def test_committed_docs_match_their_results_files():
    assert regions.check(ROOT) == []
    text = "".join((ROOT / f).read_text() for f in regions.markdown_files(ROOT))
    names = set(re.findall(r"<!-- generated: ([\w-]+) from", text))
    assert {"accuracy-table", "accuracy-facts", "peer", "effects", "verify-table", "sweep", "calibration", "peer-rows"} <= names


def test_a_changed_digit_inside_a_region_fails_the_check(tmp_path, capsys):
    files = regions.markdown_files(ROOT)
    for f in files:
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / f, tmp_path / f)
    shutil.copytree(ROOT / "bench" / "results", tmp_path / "bench" / "results")
    for f in files:                                                # sources outside bench/results (FE CSVs)
        for m in regions.REGION.finditer((ROOT / f).read_text()):
            for src in (x.strip() for x in m["sources"].split(",")):
                if not (tmp_path / src).exists():
                    (tmp_path / src).parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy(ROOT / src, tmp_path / src)
    page = next(f for f in files if "<!-- generated: verify-table" in (ROOT / f).read_text())
    readme = tmp_path / page
    text = readme.read_text()
    start = text.index("<!-- generated: verify-table")
    i = start + re.search(r"\d", text[start + 60:]).start() + 60     # a digit inside the table
    changed = text[:i] + str((int(text[i]) + 1) % 10) + text[i + 1:]
    readme.write_text(changed)
    assert cli.main(["--check", "--root", str(tmp_path)]) == 1
    assert readme.read_text() == changed                           # --check writes nothing
    assert f"+++ {page} (generated)" in capsys.readouterr().out   # the diff names the file
    assert cli.main(["--root", str(tmp_path)]) == 0             # regenerating restores it
    assert readme.read_text() == text
    outside = text.replace("Stereo-DIC measures", "Stereo DIC measures") if "Stereo-DIC measures" in text else text + "\n9\n"
    readme.write_text(outside)
    assert cli.main(["--check", "--root", str(tmp_path)]) == 0   # text outside regions is free
