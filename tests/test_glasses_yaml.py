"""``headplod glasses --out glasses.pdf`` writes the markers.yaml beside the template, as the README and
docs/live.md say (issue 36, item 3); a different markers.yaml already there is never replaced unsaid."""
import numpy as np

from headplod import io
from headplod.cli import main as cli_main

OTHER = io.MarkerModel(np.array([[70.0, 0, 0], [0, 0, 0], [-60.0, 0, 0], [35.0, -25.0, 2.0],
                                 [-45.0, -28.0, 2.0]]), 8.0)


def test_glasses_writes_markers_yaml_beside_the_template(tmp_path, capsys):
    out = tmp_path / "glasses.pdf"
    assert cli_main(["glasses", "--out", str(out)]) == 0
    assert io.read_markers(tmp_path / "markers.yaml") == io.default_marker_model()
    assert "markers.yaml" in capsys.readouterr().out
    assert cli_main(["glasses", "--marker-mm", "6", "--out", str(tmp_path / "again.svg")]) == 0   # the same layout
    assert "already holds this layout" in capsys.readouterr().out
    assert io.read_markers(tmp_path / "markers.yaml") == io.default_marker_model()


def test_a_different_markers_yaml_beside_is_kept_and_the_run_says_so(tmp_path, capsys):
    yaml = tmp_path / "markers.yaml"
    io.write_markers(yaml, OTHER)
    before = yaml.read_bytes()
    assert cli_main(["glasses", "--out", str(tmp_path / "g.pdf")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "markers.yaml" in err and "--yaml" in err, err
    assert yaml.read_bytes() == before and not (tmp_path / "g.pdf").exists()     # nothing written
    # Named on purpose: replaced, and the line says so.
    assert cli_main(["glasses", "--out", str(tmp_path / "g.pdf"), "--yaml", str(yaml)]) == 0
    assert "replacing" in capsys.readouterr().out
    assert io.read_markers(yaml) == io.default_marker_model()


def test_the_layout_drawn_from_markers_yaml_beside_is_left_as_it_is(tmp_path, capsys):
    yaml = tmp_path / "markers.yaml"
    io.write_markers(yaml, OTHER)
    before = yaml.read_bytes()
    assert cli_main(["glasses", "--markers", str(yaml), "--out", str(tmp_path / "g.svg")]) == 0
    assert yaml.read_bytes() == before and (tmp_path / "g.svg").is_file()
    # A --marker-mm that changes it is refused, not written over the file being read.
    assert cli_main(["glasses", "--markers", str(yaml), "--marker-mm", "10", "--out", str(tmp_path / "h.svg")]) == 2
    assert yaml.read_bytes() == before and not (tmp_path / "h.svg").exists()


def test_no_yaml_writes_the_template_alone(tmp_path):
    assert cli_main(["glasses", "--no-yaml", "--out", str(tmp_path / "g.svg")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.svg"]


def test_the_docs_say_what_glasses_writes():
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    for page in ("README.md", "docs/live.md"):
        text = " ".join((root / page).read_text().split())
        assert "markers.yaml` beside" in text, page
