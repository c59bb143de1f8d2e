"""Independent collision oracle for park-out results: shapely polygons of the exact car footprint."""
import numpy as np
import shapely


def car_polygons(poses, vehicle):
    """Shapely boxes of the car at rear-axle poses ``(P, 3)`` (numpy geometry, not jaxplan's)."""
    p = np.asarray(poses, float)
    a = float(vehicle.length) - float(vehicle.rear_overhang)
    ro, w = float(vehicle.rear_overhang), 0.5 * float(vehicle.width)
    loc = np.array([[a, w], [-ro, w], [-ro, -w], [a, -w]])
    c, s = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
    x = p[:, :1] + c * loc[:, 0] - s * loc[:, 1]
    y = p[:, 1:2] + s * loc[:, 0] + c * loc[:, 1]
    return shapely.polygons(np.stack([x, y], -1))


def collisions(poses, valid, polygons, poly_valid, vehicle):
    """Per scene: does any driven footprint overlap (positive area) an obstacle outline?

    Args:
        poses ``(B, M, T, 3)``, valid ``(B, M, T)``, polygons ``(B, K, N, 2)``, poly_valid ``(B, K)``.
    """
    out = np.zeros(len(poses), bool)
    for b in range(len(poses)):
        q = np.asarray(poses[b])[np.asarray(valid[b])]
        obs = [shapely.Polygon(np.asarray(polygons[b, k])).buffer(0) for k in range(polygons.shape[1])
               if bool(poly_valid[b, k])]
        if not len(q) or not obs:
            continue
        fp = car_polygons(q, vehicle)
        i, j = shapely.STRtree(obs).query(fp, predicate="intersects")
        out[b] = any(shapely.intersection(fp[a], obs[c]).area > 1e-9 for a, c in zip(i, j))
    return out


def clearance(poses, valid, polygons, poly_valid, vehicle):
    """Per scene: smallest distance from a driven footprint to an obstacle outline."""
    out = np.full(len(poses), np.inf)
    for b in range(len(poses)):
        q = np.asarray(poses[b])[np.asarray(valid[b])]
        obs = [shapely.Polygon(np.asarray(polygons[b, k])) for k in range(polygons.shape[1]) if bool(poly_valid[b, k])]
        if len(q) and obs:
            out[b] = float(np.min(shapely.distance(car_polygons(q, vehicle)[:, None], np.array(obs)[None])))
    return out


def centre_box_polygons(states, vehicle):
    """Shapely boxes of the car at box-centre states ``(S, >=3)`` [x, y, heading, ...]."""
    s = np.asarray(states, float)
    hl, w = 0.5 * float(vehicle.length), 0.5 * float(vehicle.width)
    loc = np.array([[hl, w], [-hl, w], [-hl, -w], [hl, -w]])
    c, n = np.cos(s[:, 2])[:, None], np.sin(s[:, 2])[:, None]
    x = s[:, :1] + c * loc[:, 0] - n * loc[:, 1]
    y = s[:, 1:2] + n * loc[:, 0] + c * loc[:, 1]
    return shapely.polygons(np.stack([x, y], -1))


def world_collision(states, obstacle_polygons, vehicle):
    """Does any box-centre state's footprint overlap (positive area) a world obstacle outline?"""
    obs = [shapely.Polygon(np.asarray(p)).buffer(0) for p in obstacle_polygons]
    fp = centre_box_polygons(states, vehicle)
    i, j = shapely.STRtree(obs).query(fp, predicate="intersects")
    return any(shapely.intersection(fp[a], obs[c]).area > 1e-9 for a, c in zip(i, j))
