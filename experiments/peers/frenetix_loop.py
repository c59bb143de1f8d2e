"""Frenetix's sampling loop around the ``frenetix`` package (its C++ sampler, cost and feasibility
functions): the candidates of one planning cycle, ranked by cost, the cheapest one free of every
obstacle and of the road boundary, else Frenetix's stopping choice. Runs in Frenetix's virtual
environment; ``frenetix`` and commonroad-drivability-checker are imported where they are used."""

from __future__ import annotations

import math

import numpy as np


class _FrenetixLoop:
    """Frenetix's sampling loop around ``frenetix`` 0.4.0 (after frenetix-motion-planner's
    ``ReactivePlannerCpp.plan``; the C++ functions are frenetix's own)."""

    HORIZON, T_MIN, D_MIN, D_MAX, LEVEL = 3.0, 1.1, -3.0, 3.0, 2
    WEIGHTS = {
        "lateral_jerk": 1.0,
        "longitudinal_jerk": 1.0,
        "velocity_offset": 1.0,
        "distance_to_reference_path": 3.0,
        "prediction": 200.0,
    }

    def __init__(self, sc, pp, route: np.ndarray, v_set: float):
        import frenetix
        from commonroad_dc.boundary.boundary import create_road_boundary_obstacle
        from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import create_collision_checker
        from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

        self.fx, self.sc, self.pp, self.v_set = frenetix, sc, pp, v_set
        self.car = parameters_vehicle2()
        self.wheelbase = self.car.a + self.car.b
        self.dt = float(sc.dt)
        self.N = int(round(self.HORIZON / self.dt))
        self.cs = frenetix.CoordinateSystemWrapper(np.ascontiguousarray(route, dtype=np.float64))
        self.cc = create_collision_checker(sc)
        _, road = create_road_boundary_obstacle(sc)
        self.cc.add_collision_object(road)

    def _handler(self, x0, k: int, low_v: bool):
        import frenetix.trajectory_functions as tf
        import frenetix.trajectory_functions.cost_functions as cf
        import frenetix.trajectory_functions.feasability_functions as ff

        c, w = self.car, self.WEIGHTS
        h = self.fx.TrajectoryHandler(dt=self.dt)
        h.add_feasability_function(
            ff.CheckYawRateConstraint(deltaMax=c.steering.max, wheelbase=self.wheelbase, wholeTrajectory=False)
        )
        h.add_feasability_function(
            ff.CheckAccelerationConstraint(
                switchingVelocity=c.longitudinal.v_switch, maxAcceleration=c.longitudinal.a_max, wholeTrajectory=False
            )
        )
        h.add_feasability_function(
            ff.CheckCurvatureConstraint(deltaMax=c.steering.max, wheelbase=self.wheelbase, wholeTrajectory=False)
        )
        h.add_feasability_function(
            ff.CheckCurvatureRateConstraint(
                wheelbase=self.wheelbase, velocityDeltaMax=c.steering.v_max, wholeTrajectory=False
            )
        )
        h.add_cost_function(cf.CalculateLateralJerkCost("lateral_jerk", w["lateral_jerk"]))
        h.add_cost_function(cf.CalculateLongitudinalJerkCost("longitudinal_jerk", w["longitudinal_jerk"]))
        h.add_cost_function(
            cf.CalculateDistanceToReferencePathCost("distance_to_reference_path", w["distance_to_reference_path"])
        )
        h.add_function(
            tf.FillCoordinates(
                lowVelocityMode=low_v,
                initialOrientation=float(x0[2]),
                coordinateSystem=self.cs,
                horizon=int(self.HORIZON),
            )
        )
        h.add_cost_function(
            cf.CalculateCollisionProbabilityFast("prediction", w["prediction"], self._predictions(k), c.l, c.w, c.b)
        )
        h.add_cost_function(
            cf.CalculateVelocityOffsetCost(
                "velocity_offset",
                w["velocity_offset"],
                self.v_set,
                self.dt,
                self.T_MIN,
                limit_to_t_min=False,
                norm_order=2,
            )
        )
        return h

    def _predictions(self, k: int) -> dict:
        """Every obstacle's recorded future over the horizon (static ones held), fixed small covariance."""
        cov = np.zeros((6, 6))
        cov[:2, :2] = 0.1 * np.eye(2)
        cov = np.asfortranarray(cov)
        out = {}
        for o in self.sc.obstacles:
            path = []
            for j in range(self.N + 1):
                occ = o.state_at_time(k + j) if o.obstacle_role.value == "dynamic" else o.initial_state
                if occ is None:
                    break
                th = float(occ.orientation)
                path.append(
                    self.fx.PoseWithCovariance(
                        np.array([*map(float, occ.position), 0.0]),
                        np.array([0.0, 0.0, math.sin(th / 2), math.cos(th / 2)]),
                        cov,
                    )
                )
            shape = o.obstacle_shape
            if len(path) > 1 and hasattr(shape, "length"):
                out[int(o.obstacle_id)] = self.fx.PredictedObject(
                    int(o.obstacle_id), path, float(shape.length), float(shape.width)
                )
        return out

    def _levels(self, v: float):
        """End times, speeds and offsets at Frenetix's sampling level (its density rule)."""
        a = self.car.longitudinal.a_max
        lo, hi = (
            max(0.01, v - 0.5 * a * self.HORIZON),
            min(v + a / 7.0 * self.HORIZON, 36.0, self.car.longitudinal.v_max),
        )
        n = 3
        for _ in range(self.LEVEL):
            n = 2 * n - 1
        step = int((1 / (self.LEVEL + 1)) / self.dt) * self.dt
        t1 = set(np.round(np.arange(self.T_MIN, self.HORIZON + self.dt, step), 2)) | {round(self.N * self.dt, 2)}
        t1 = {t for t in t1 if t <= self.HORIZON + 1e-9}
        return np.array(sorted(t1)), np.linspace(lo, hi, n), np.linspace(self.D_MIN, self.D_MAX, n)

    def collides(self, traj) -> bool:
        """Candidate's centre boxes from the next step on against every obstacle and the road boundary."""
        from commonroad_dc import pycrcc

        x, y, th = np.asarray(traj.cartesian.x), np.asarray(traj.cartesian.y), np.asarray(traj.cartesian.theta)
        tvo = pycrcc.TimeVariantCollisionObject(self.k + 1)
        for i in range(1, len(x)):
            tvo.append_obstacle(
                pycrcc.RectOBB(
                    0.5 * self.car.l,
                    0.5 * self.car.w,
                    float(th[i]),
                    float(x[i] + self.car.b * math.cos(th[i])),
                    float(y[i] + self.car.b * math.sin(th[i])),
                )
            )
        return bool(self.cc.collide(tvo))

    def plan(self, x0, k: int, x_cl=None):
        """One planning cycle from rear-axle state ``x0 = (x, y, theta, v, a)`` at step ``k``.

        Returns:
            ``(trajectory sample or None, candidates sampled, mode)``.
        """
        self.k = k
        low_v = x0[3] < 2.0
        if x_cl is None:
            init = self.fx.TrajectorySample(
                x0=float(x0[0]),
                y0=float(x0[1]),
                orientation0=float(x0[2]),
                acceleration0=float(x0[4]),
                velocity0=float(x0[3]),
            )
            self.fx.trajectory_functions.ComputeInitialState(
                coordinateSystem=self.cs, wheelBase=self.wheelbase, steeringAngle=0.0, lowVelocityMode=low_v
            ).evaluate_trajectory(init)
            c = init.curvilinear
            f0 = lambda a: float(np.asarray(a).ravel()[0])  # noqa: E731
            lon, lat = [f0(c.s), f0(c.s_dot), f0(c.s_ddot)], [f0(c.d), f0(c.d_dot), f0(c.d_ddot)]
        else:
            lon, lat = x_cl
        t1, v1, d1 = self._levels(x0[3])
        v1 = np.union1d(v1, [lon[1]])
        d1 = np.union1d(d1, [lat[0]])
        grid = np.array(np.meshgrid(t1, v1, d1, indexing="ij")).reshape(3, -1).T
        M = np.zeros((len(grid), 13))
        M[:, 1], M[:, 5], M[:, 10] = grid[:, 0], grid[:, 1], grid[:, 2]
        M[:, 2], M[:, 3], M[:, 4] = lon
        M[:, 7], M[:, 8], M[:, 9] = lat
        h = self._handler(x0, k, low_v)
        h.reset_Trajectories()
        h.generate_trajectories(M, low_v)
        h.evaluate_all_current_functions(True)
        feasible = [t for t in h.get_sorted_trajectories() if t.feasible]
        for t in feasible:
            if not self.collides(t):
                return t, len(M), "optimal"
        if feasible:  # Frenetix's "stopping" emergency mode
            stop = min(
                feasible,
                key=lambda t: (
                    round(t.sampling_parameters[5], 6),
                    round(t.sampling_parameters[1], 6),
                    abs(t.sampling_parameters[10] - lat[0]),
                ),
            )
            return stop, len(M), "stopping"
        return None, len(M), "none feasible"
