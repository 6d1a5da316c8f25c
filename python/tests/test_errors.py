"""Bad input becomes a gpm exception naming the parameter or the particle; never a crash."""

from __future__ import annotations

import numpy as np
import pytest

import gpm


def periodic_system(n=12, **kw):
    dx = 1.0 / n
    x = gpm.lattice([0.0, 0.0], [1.0, 1.0], dx)
    u = np.stack([np.sin(2 * np.pi * x[:, 1]), np.cos(2 * np.pi * x[:, 0])], axis=1)
    kw.setdefault("h", 3 * dx)
    kw.setdefault("boundary", gpm.Boundary.periodic([0, 0], [1, 1]))
    return gpm.System(x, u, **kw), x, u


def test_hierarchy():
    assert issubclass(gpm.InputError, gpm.GpmError)
    assert issubclass(gpm.InputError, ValueError)
    for cls in (gpm.ConnectivityError, gpm.SolveError, gpm.StabilityError, gpm.RecordError,
                gpm.PairWeightError):
        assert issubclass(cls, gpm.GpmError)


def test_bad_array_shape_names_the_array():
    x = np.zeros((10, 4))
    with pytest.raises(gpm.InputError) as e:
        gpm.System(x, x, h=0.1)
    assert e.value.parameter == "x"
    assert "(n, 2) or (n, 3)" in str(e.value)
    sys_, x, u = periodic_system()
    with pytest.raises(gpm.InputError) as e:
        gpm.System(x, u[:-1], h=0.25)
    assert e.value.parameter == "u" and f"({len(x)}, 2)" in str(e.value)
    with pytest.raises(gpm.InputError) as e:
        sys_.predict(0.01, accel=np.zeros((len(x), 3)))
    assert e.value.parameter == "accel"
    with pytest.raises(gpm.InputError) as e:
        sys_.project(0.01, np.zeros((len(x) + 1, 2)))
    assert e.value.parameter == "u_star"
    with pytest.raises(gpm.InputError) as e:
        sys_.x = np.zeros((3, 2))
    assert e.value.parameter == "x"
    with pytest.raises(gpm.InputError) as e:
        sys_.p = np.zeros(len(x) - 1)
    assert e.value.parameter == "p"
    with pytest.raises(gpm.InputError) as e:
        sys_.project(0.01, "not an array")
    assert e.value.parameter == "u_star"


def test_nan_velocity_names_the_particle():
    sys_, x, u = periodic_system()
    u_bad = u.copy()
    u_bad[7, 1] = np.nan
    sys_.u = u_bad
    p_before = sys_.p
    with pytest.raises(gpm.InputError) as e:
        sys_.predict(0.01)
    assert e.value.particle == 7 and e.value.parameter == "u"
    assert "particle 7" in str(e.value)
    # u* with an infinite entry: project refuses it and leaves u and p unchanged
    sys_.u = u
    u_star = u.copy()
    u_star[3, 0] = np.inf
    with pytest.raises(gpm.InputError) as e:
        sys_.project(0.01, u_star)
    assert e.value.particle == 3 and e.value.parameter == "u_star"
    assert np.array_equal(sys_.u, u) and np.array_equal(sys_.p, p_before)


def test_nan_position_names_the_particle():
    sys_, x, u = periodic_system()
    x_bad = x.copy()
    x_bad[5, 0] = np.nan
    sys_.x = x_bad
    with pytest.raises(gpm.InputError) as e:
        sys_.update_neighbors()
    assert e.value.particle == 5
    assert "5" in str(e.value)


@pytest.mark.parametrize("dt", [0.0, -1.0, float("nan"), float("inf")])
def test_non_positive_dt_names_dt(dt):
    sys_, x, u = periodic_system()
    for call in (lambda: sys_.predict(dt), lambda: sys_.project(dt, u), lambda: sys_.step(dt)):
        with pytest.raises(gpm.InputError) as e:
            call()
        assert e.value.parameter == "dt"
        assert "time step" in str(e.value)


def test_bad_parameters_name_the_key():
    with pytest.raises(gpm.InputError) as e:
        periodic_system(nu=-1.0)
    assert e.value.parameter == "nu"
    with pytest.raises(gpm.InputError) as e:
        periodic_system(rho=0.0)
    assert e.value.parameter == "rho"
    with pytest.raises(gpm.InputError) as e:
        periodic_system(scheme="chorinx")
    assert e.value.parameter == "scheme" and "unknown scheme" in str(e.value)
    with pytest.raises(gpm.InputError) as e:
        periodic_system(weight="gauss")
    assert e.value.parameter == "weight"
    with pytest.raises(gpm.InputError) as e:
        periodic_system(solve={"rel_tol": -1.0})
    assert e.value.parameter == "solve.rel_tol"
    with pytest.raises(gpm.InputError) as e:
        periodic_system(solve={"no_such_key": 1})
    assert e.value.parameter is not None and "no_such_key" in str(e.value)
    with pytest.raises(gpm.InputError) as e:
        periodic_system(gravity=[0.0, -9.8, 0.0])
    assert e.value.parameter == "gravity"
    with pytest.raises(gpm.InputError) as e:
        periodic_system(h=0.5 / 12)  # h below the spacing 1/12
    assert e.value.parameter == "h"
    with pytest.raises(gpm.InputError) as e:
        periodic_system(h=-1.0)
    assert e.value.parameter == "h"


def test_stale_neighbours_name_the_particle():
    sys_, x, u = periodic_system()
    x2 = x.copy()
    x2[4] += [0.01, 0.0]
    sys_.x = x2  # moved without update_neighbors
    with pytest.raises(gpm.InputError) as e:
        sys_.project(0.01, u)
    assert e.value.particle is not None
    assert "out of date" in str(e.value) and "update_neighbors" in str(e.value)


def test_connectivity_names_the_offending_particles():
    # two lattices far apart in free space: two floating components where one is allowed
    dx = 0.1
    a = gpm.lattice([0.0, 0.0], [0.5, 0.5], dx)
    x = np.concatenate([a, a + [5.0, 5.0]])
    u = np.zeros_like(x)
    sys_ = gpm.System(x, u, h=2.5 * dx, scheme="non_incremental")
    with pytest.raises(gpm.ConnectivityError) as e:
        sys_.project(0.1, u)
    assert sorted(e.value.offending) == list(range(len(a), 2 * len(a)))
    assert e.value.particle == len(a)
    assert "h-connectivity" in str(e.value)


def test_recorder_errors():
    with pytest.raises(gpm.RecordError) as e:
        gpm.Recorder("/nonexistent-dir/sub/run.mcap")
    assert "/nonexistent-dir/sub" in str(e.value)
    with pytest.raises(gpm.InputError) as e:
        gpm.Recorder("/tmp/x.mcap", level="everything")
    assert e.value.parameter == "level"


def test_unknown_scene_and_key():
    with pytest.raises(gpm.InputError) as e:
        gpm.run_scene("no_such_scene")
    assert e.value.parameter == "scene"
    with pytest.raises(gpm.InputError) as e:
        gpm.run_scene("cavity", {"n": 12, "not_a_key": 1})
    assert "not_a_key" in str(e.value)
