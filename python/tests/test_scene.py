"""Running a ready-made scene from Python."""

from __future__ import annotations

import io

import numpy as np

import gpm


def test_cavity_scene_runs_and_reports(tmp_path):
    assert "cavity" in gpm.SCENES
    out = gpm.run_scene("cavity", {"n": 12, "t_end": 0.3}, record=tmp_path / "run.mcap")
    assert out["scene"] == "cavity" and out["steps"] > 0
    assert set(out["tables"]) >= {"profile_u.csv", "profile_v.csv"}
    prof = np.genfromtxt(io.StringIO(out["tables"]["profile_u.csv"]), delimiter=",", names=True)
    assert len(prof) > 0 and np.all(np.isfinite(prof.view(np.float64)))
    assert out["record"]["steps"] == out["steps"]
    assert (tmp_path / "run.mcap").exists()
    assert isinstance(out["summary"], dict) and out["summary"]
