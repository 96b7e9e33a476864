"""``mimica landmarks FOLDER``: local workers, a Dask cluster, the summary CSV, resume, and a broken
scan that never stops the batch."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from app import cli


@pytest.fixture(scope="module")
def scan_folder(tmp_path_factory):
    """Two virtual scans of the default model and one file that is not a mesh."""
    from core.formats.mesh_io import save_face
    from core.registration.pipeline import default_model
    from core.registration.virtual_scanner import scan_face

    folder = tmp_path_factory.mktemp("scans")
    for k in (1, 2):
        save_face(scan_face(default_model(), n_target=8_000, rng=np.random.default_rng(k)).face, folder / f"p{k}.ply")
    (folder / "broken.ply").write_text("ply\nthis is not a mesh\n")
    return folder


def _summary(out):
    with open(out / "summary.csv", newline="", encoding="utf-8") as fh:
        return {row["scan"]: row for row in csv.DictReader(fh)}


def test_a_folder_in_two_workers_with_summary_and_resume(scan_folder, tmp_path, capsys):
    out = tmp_path / "landmarks"
    assert cli.main(["landmarks", str(scan_folder), "-o", str(out), "--workers", "2"]) == 1   # one scan failed
    printed = capsys.readouterr()
    assert "1 of 3 scan(s) could not be landmarked" in printed.err and "Traceback" not in printed.err
    assert sorted(p.name for p in out.glob("*.landmarks.json")) == ["p1.landmarks.json", "p2.landmarks.json"]
    rows = _summary(out)
    assert list(rows) == ["broken.ply", "p1.ply", "p2.ply"], "the folder's order, not the finishing order"
    assert rows["broken.ply"]["status"] == "failed" and "broken.ply" in rows["broken.ply"]["message"]
    for name in ("p1.ply", "p2.ply"):
        row = rows[name]
        assert row["status"] == "ok" and float(row["seconds"]) > 0
        assert 0.5 < float(row["scan_confidence"]) <= 1.0 and int(row["low_confidence"]) >= 0
    # Resume: finished scans are skipped, the broken one is tried again.
    before = {p.name: p.stat().st_mtime_ns for p in out.glob("*.landmarks.json")}
    assert cli.main(["landmarks", str(scan_folder), "-o", str(out), "--resume"]) == 1
    rows = _summary(out)
    assert [rows[n]["status"] for n in ("broken.ply", "p1.ply", "p2.ply")] == ["failed", "skipped", "skipped"]
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.landmarks.json")} == before
    assert "2 of 3 scan(s) already done" in capsys.readouterr().err


def test_a_folder_on_a_local_dask_cluster(scan_folder, tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    out = tmp_path / "landmarks"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        code = cli.main(["landmarks", str(scan_folder), "-o", str(out), "--scheduler", cluster.scheduler_address])
    assert code == 1
    rows = _summary(out)
    assert [rows[n]["status"] for n in ("broken.ply", "p1.ply", "p2.ply")] == ["failed", "ok", "ok"]
    assert (out / "p1.landmarks.json").is_file() and (out / "p2.landmarks.json").is_file()


def test_an_unreachable_scheduler_is_a_clear_error(scan_folder, tmp_path, capsys):
    pytest.importorskip("distributed")
    code = cli.main(["landmarks", str(scan_folder), "-o", str(tmp_path / "l"), "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert code != 0 and "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in err and "Traceback" not in err


def test_register_a_folder_in_two_workers(scan_folder, tmp_path, capsys):
    landmarks, canonical = tmp_path / "landmarks", tmp_path / "canonical"
    cli.main(["landmarks", str(scan_folder), "-o", str(landmarks), "--workers", "2"])
    capsys.readouterr()
    assert cli.main(["register", str(scan_folder), "-l", str(landmarks), "-o", str(canonical), "--workers", "2"]) == 1
    rows = _summary(canonical)
    assert [rows[n]["status"] for n in ("broken.ply", "p1.ply", "p2.ply")] == ["failed", "ok", "ok"]
    assert "4560 vertices" in rows["p1.ply"]["message"]
    assert sorted(p.name for p in canonical.glob("*.canonical.obj")) == ["p1.canonical.obj", "p2.canonical.obj"]
    assert cli.main(["register", str(scan_folder), "-l", str(landmarks), "-o", str(canonical), "--resume"]) == 1
    assert [_summary(canonical)[n]["status"] for n in ("p1.ply", "p2.ply")] == ["skipped", "skipped"]
