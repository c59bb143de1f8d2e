"""The one geometry core every planner uses."""
from jaxplan.geometry.boxes import (
    box_corners,
    box_has_overlap,
    box_separation,
    headings_from_path,
    poses_to_boxes,
    vehicle_corners,
)
from jaxplan.geometry.frenet import (
    ReferenceLine,
    frenet_to_cartesian_state,
    ref_state,
    reference_line,
    to_cartesian,
    to_frenet,
    wrap_angle,
)
from jaxplan.geometry.lines import (
    cross2,
    dot2,
    line_intersection,
    normalize,
    perpendicular,
    point_on_segment,
    project_point,
    safe_norm,
    safe_sqrt,
    segment_point_distance,
)
from jaxplan.geometry.polygons import (
    CORNER_OF_A,
    CORNER_OF_B,
    EDGE_CROSSING,
    OverlapPolygon,
    has_overlap,
    overlap_area,
    overlap_polygon,
    overlap_polygon_tagged,
    points_in_polygon,
    points_in_simple_polygon,
    polygon_area,
    polygon_edges,
    separation,
)

__all__ = ["CORNER_OF_A", "CORNER_OF_B", "EDGE_CROSSING", "OverlapPolygon", "ReferenceLine", "box_corners",
           "box_has_overlap", "box_separation", "cross2", "dot2", "frenet_to_cartesian_state", "has_overlap",
           "headings_from_path", "line_intersection", "normalize", "overlap_area", "overlap_polygon",
           "overlap_polygon_tagged", "perpendicular", "point_on_segment", "points_in_polygon",
           "points_in_simple_polygon", "polygon_area", "polygon_edges", "poses_to_boxes", "project_point", "ref_state",
           "reference_line", "safe_norm", "safe_sqrt", "segment_point_distance", "separation", "to_cartesian",
           "to_frenet", "vehicle_corners", "wrap_angle"]
