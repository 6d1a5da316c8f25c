"""Recording from Python: the file is read back by the independent `mcap` reader."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

import gpm
from conftest import load_example, read_diagnostics


def test_recorded_own_loop_reads_back(tmp_path):
    own_loop = load_example("own_loop")
    path = tmp_path / "run.mcap"
    cfg = {"n": 24, "steps": 7, "dt": 0.002, "drag": 0.1}
    with gpm.Recorder(path, level="full", every=3, config=cfg) as rec:
        reports = own_loop.user_loop(**cfg, recorder=rec)
    assert path.exists() and not (tmp_path / "run.mcap.partial").exists()

    from mcap.reader import make_reader

    topics = Counter()
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        for schema, channel, message in reader.iter_messages():
            topics[channel.topic] += 1
            data = json.loads(message.data)
            if channel.topic == "/particles":
                assert data["point_stride"] > 0
            if channel.topic == "/projection_input":
                assert data["particles"] == 24 * 24 and data["dimension"] == 2
    assert schemas["/diagnostics"] == "gpm.StepDiagnostics"
    assert schemas["/particles"] == "foxglove.PointCloud"
    # snapshots and projection inputs at steps 1, 4, 7
    assert topics == {"/config": 1, "/diagnostics": 7, "/particles": 3, "/projection_input": 3}

    config, steps = read_diagnostics(path)
    assert config["config"] == cfg and config["level"] == "full"
    assert [s["step"] for s in steps] == list(range(1, 8))
    for s, r in zip(steps, reports):
        # JSON keeps every digit: the recorded numbers are the reported ones
        assert s["div_before"] == r.div_before and s["div_after"] == r.div_after
        assert s["kinetic_energy"] == r.kinetic_energy and s["c0"] == r.c0
        assert s["time"] == pytest.approx(s["step"] * 0.002, rel=1e-15)


def test_python_recording_equals_the_rust_recording(rust_own_loop, tmp_path):
    own_loop = load_example("own_loop")
    assert own_loop.main(["--out", str(tmp_path)]) == 0
    rust_cfg, rust = read_diagnostics(rust_own_loop)
    py_cfg, py = read_diagnostics(tmp_path / "run.mcap")
    assert py_cfg["config"] == rust_cfg["config"]
    assert len(py) == len(rust) == 20
    for a, b in zip(rust, py):
        for key in ("div_before", "div_after", "stability_ratio", "kinetic_energy"):
            assert abs(a[key] - b[key]) <= 1e-12 * abs(a[key]), (a["step"], key)


def test_finish_twice_and_record_after_finish(tmp_path):
    dx = 1.0 / 12
    x = gpm.lattice([0, 0], [1, 1], dx)
    sys_ = gpm.System(x, np.zeros_like(x), h=3 * dx,
                      boundary=gpm.Boundary.periodic([0, 0], [1, 1]))
    r = sys_.step(0.01)
    rec = gpm.Recorder(tmp_path / "a.mcap")
    rec.record(sys_, r, 1, 0.01)
    s = rec.finish()
    assert s["steps"] == 1 and s["messages"]["/diagnostics"] == 1
    with pytest.raises(gpm.RecordError):
        rec.finish()
    with pytest.raises(gpm.RecordError):
        rec.record(sys_, r, 2, 0.02)
    with pytest.raises(gpm.InputError) as e:
        gpm.Recorder(tmp_path / "b.mcap").record(sys_, r, 0, 0.0)
    assert e.value.parameter == "step"


def test_a_failed_block_keeps_the_steps_as_failed_file(tmp_path):
    dx = 1.0 / 12
    x = gpm.lattice([0, 0], [1, 1], dx)
    sys_ = gpm.System(x, np.zeros_like(x), h=3 * dx,
                      boundary=gpm.Boundary.periodic([0, 0], [1, 1]))
    with pytest.raises(gpm.InputError):
        with gpm.Recorder(tmp_path / "run.mcap") as rec:
            rec.record(sys_, sys_.step(0.01), 1, 0.01)
            sys_.step(-1.0)  # fails: dt
    assert not (tmp_path / "run.mcap").exists()
    _, steps = read_diagnostics(tmp_path / "run.failed.mcap")
    assert [s["step"] for s in steps] == [1]
