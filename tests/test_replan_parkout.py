"""The park-out planner driven by the replanning supervisor through the planner callback.

A park-out move ends where the footprint grown by the planner's margin (0.05-0.1 m on its
grid) would touch the parked cars, so the supervisor must not grow the car by more than the
planner keeps (``ParkoutPlanner.clearance``): with its default 0.15 m it rejected every
plan, and the car stood in its slot for the whole drive.
"""
import jax
import numpy as np
import pytest


def test_parkout_through_lazy_supervisor():
    from jaxplan.parking import is_out, stop_line
    from jaxplan.replan import LAZY, OBSTACLE, ManeuverSimConfig, SupervisorConfig, simulate_host
    from jaxplan.replan.parkout_adapter import ParkoutPlanner, parkout_scenarios
    from jaxplan.replan.trajectory import sub_trajectories

    pp = ParkoutPlanner()
    sc, nominal = parkout_scenarios(0, 2, pp)
    lo, hi, dirs, count = jax.vmap(sub_trajectories)(nominal.traj.gear, nominal.valid)
    assert np.all(np.asarray(count) >= 2)  # a multi-move park-out: gear shifts between moves
    sup = SupervisorConfig(limits=pp.limits, clearance=pp.clearance)
    cfg = ManeuverSimConfig(planner=pp, supervisor=sup, sensor_range=30.0, lat_sigma=0.0, steps=300)
    d = stop_line(pp.vehicle, pp.config.c)
    for i in range(2):
        fin, logs = simulate_host(jax.tree.map(lambda a: a[i], sc), LAZY, cfg)
        assert bool(fin.done) and not bool(fin.collided)
        assert bool(is_out(fin.pose, d, pp.config))
        assert int(fin.sup.n_replan_moving) == 0
        v = np.array([abs(float(lg.v)) for lg in logs])
        ev = [j for j, lg in enumerate(logs) if bool(lg.replan)]
        assert ev, "the phantom on the way out should stop the car once"
        for j in ev:
            assert v[j - 1] < sup.v_stopped and int(logs[j].reason) == OBSTACLE
        # One stop: the car stands from its first re-plan to its last, then drives out.
        assert np.all(v[ev[0] - 1 : ev[-1] + 1] < sup.v_stopped)
        assert np.max(v[ev[-1] :]) > 0.5


def test_supervisor_clearance_above_the_planners_is_refused():
    from jaxplan.replan import ManeuverSimConfig, SupervisorConfig
    from jaxplan.replan.parkout_adapter import ParkoutPlanner

    pp = ParkoutPlanner()
    assert 0.0 < pp.clearance < SupervisorConfig().clearance
    with pytest.raises(ValueError, match="clearance"):
        ManeuverSimConfig(planner=pp, supervisor=SupervisorConfig(limits=pp.limits))
