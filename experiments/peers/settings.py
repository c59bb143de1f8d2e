"""The settings table of a comparison: every setting that differs between the planners (the peers
and jaxplan's road planners, whose horizon and car are read from jaxplan) with the reason, and those
that are equal; ``render_settings`` writes it as Markdown."""

from __future__ import annotations

import sys

from .config import CAR_LENGTH, CAR_WIDTH, PEERS, ROOT, ROUTE_BUILDER


def _jaxplan_planner_facts(names) -> dict:
    """``{name: {"horizon": s, "vehicle": "L x W, wheelbase"}}`` read from jaxplan's planners
    (their defaults as ``jaxplan drive`` builds them); an entry says why where they cannot be read."""
    out = {}
    try:
        sys.path.insert(0, ROOT)
        from jaxplan.planner import get_factory
    except Exception as e:  # noqa: BLE001 - the table then says so
        return {n: {"error": f"{type(e).__name__}: {e}"} for n in names}
    for n in names:
        try:
            p = get_factory(n)()
            v = p.vehicle
            out[n] = {
                "horizon": f"{float(p.horizon):g} s",
                "vehicle": f"{float(v.length):g} m x {float(v.width):g} m, wheelbase {float(v.wheelbase):g} m",
            }
        except Exception as e:  # noqa: BLE001
            out[n] = {"error": f"{type(e).__name__}: {str(e)[:80]}"}
    return out


def settings_table(args, labels: list) -> dict:
    """The settings of every planner in the comparison: ``{"differ": [...], "equal": [...]}``, rows
    ``{"setting", <planner>: value, ..., "why"}``. jaxplan's road planners are listed too (their horizon
    and car read from jaxplan), so that a later ``jaxplan drive`` on ``sample.json``'s files is judged
    against the same table."""
    peers = [p for p in PEERS if p in labels]
    jp = ["lattice", "pathspeed"]
    extra = [lab for lab in labels if lab not in PEERS and lab.replace("jaxplan-", "") not in jp]
    facts = _jaxplan_planner_facts(jp)
    try:
        import importlib.util

        has_lights = importlib.util.find_spec("jaxplan.scenarios.lights") is not None
    except (ImportError, ValueError):
        has_lights = False
    lights = "read from the scene (jaxplan.scenarios.lights)" if has_lights else "not obeyed"
    cols = peers + [f"jaxplan {n}" for n in jp]
    hz = args.reactive_horizon_steps * 0.1

    def row(setting, values: dict, why: str):
        r = {"setting": setting}
        for c in cols:
            r[c] = values.get(c, values.get("*", "-"))
        r["why"] = why
        return r

    def jf(n, k):
        f = facts[n]
        return f.get(k, f"not read ({f.get('error', '?')})")

    differ = [
        row(
            "planning horizon",
            {
                "reactive": f"{hz:g} s ({args.reactive_horizon_steps} steps)",
                "frenetix": "3 s",
                **{f"jaxplan {n}": jf(n, "horizon") for n in jp},
            },
            "each planner's shipped configuration (the reactive planner's scenario configurations use 2 s, "
            "Frenetix's 3 s); the horizon is part of how a planner plans, not of the harness",
        ),
        row(
            "sampling",
            {
                "reactive": f"its sampling levels 1..4 (first level with a feasible collision-free "
                f"candidate), end times {args.reactive_t_min:g}..{hz:g} s, offsets -3..3 m, "
                "velocity keeping",
                "frenetix": "level 2: end times 1.1..3 s, 5 end speeds in [v - 0.5 a_max T, v + a_max T / 7] "
                "(and the current one), 5 offsets -3..3 m (and the current one)",
                "jaxplan lattice": "jaxplan's lattice (LatticeConfig.road)",
                "jaxplan pathspeed": "path then speed optimisation (no sampling)",
            },
            "each planner's own method and shipped settings",
        ),
        row(
            "set speed rule",
            {
                "reactive": "fixed per scenario (rule below), set with set_desired_velocity each cycle",
                "frenetix": "fixed per scenario (rule below), velocity-offset cost",
                "jaxplan lattice": "its own: speed limit ahead, bent to the goal's time and speed window, "
                "capped for curves",
                "jaxplan pathspeed": "its own: lowest speed limit ahead, lowered or raised to meet "
                "the goal's time window",
            },
            "the peers take one desired speed from outside, jaxplan's planners compute theirs from the map in "
            "every cycle; the peers' fixed speed: the middle of the goal's speed interval (capped at the "
            "start lanelet's limit), else that limit, else route distance to the goal centre over the middle "
            "of the goal's time interval (2..36 m/s), else the start speed",
        ),
        row(
            "route start",
            {
                "reactive": "route extended 10 m straight backwards",
                "frenetix": "route extended 10 m straight backwards",
                "*": "route as given",
            },
            "the peers plan from the rear axle, which can lie behind the route's first point",
        ),
        row(
            "collision check inside the planner",
            {
                "reactive": "its own (commonroad-drivability-checker: obstacles' recorded futures, road boundary)",
                "frenetix": "commonroad-drivability-checker on the ranked candidates (obstacles, road boundary); "
                "collision-probability cost on the recorded futures",
                "jaxplan lattice": "jaxplan's own geometry",
                "jaxplan pathspeed": "jaxplan's own geometry",
            },
            "each planner's method",
        ),
        row(
            "cost function",
            {
                "reactive": "its shipped cost function",
                "frenetix": "its shipped weights (jerk, "
                "velocity offset, distance to the reference path, collision probability)",
                "jaxplan lattice": "jaxplan's",
                "jaxplan pathspeed": "jaxplan's",
            },
            "each planner's method",
        ),
        row(
            "no trajectory found",
            {
                "reactive": "go on along the previous plan, then brake at 8 m/s^2",
                "frenetix": "Frenetix's stopping choice among the feasible candidates; none "
                "feasible: previous plan, then brake at 8 m/s^2",
                "jaxplan lattice": "the planner's own fallback; a plan that is not finite: brake at 8 m/s^2",
                "jaxplan pathspeed": "the planner's own fallback; a plan that is not finite: brake at 8 m/s^2",
            },
            "Frenetix ships an emergency mode, the reactive planner none; the harness's brake is the same",
        ),
    ]
    equal = [
        row("re-plan period", {"*": f"every {args.replan} steps of 0.1 s"}, "the harness"),
        row("tracking", {"*": "perfect (the car follows the chosen plan exactly)"}, "the harness"),
        row(
            "step cap",
            {"*": f"end of the goal's time interval, at most --max-steps {args.max_steps}; ends at the goal"},
            "the harness",
        ),
        row("time step", {"*": "0.1 s (the scenarios')"}, "the scenarios"),
        row(
            "route",
            {"*": f"{ROUTE_BUILDER or 'commonroad-route-planner'} (routes.json)"},
            "one route per scenario for every planner",
        ),
        row(
            "vehicle",
            {
                "reactive": f"{CAR_LENGTH:g} m x {CAR_WIDTH:g} m, wheelbase 2.578 m",
                "frenetix": f"{CAR_LENGTH:g} m x {CAR_WIDTH:g} m, wheelbase 2.578 m",
                **{f"jaxplan {n}": jf(n, "vehicle") for n in jp},
            },
            "the BMW 320i (CommonRoad vehicle type 2), the peers' default car; the referee judges this box",
        ),
        row(
            "obstacles seen",
            {"*": "every obstacle's recorded future (static ones at every time)"},
            "as CommonRoad benchmarks give them",
        ),
        row(
            "traffic lights",
            {"reactive": "not obeyed", "frenetix": "not obeyed", **{f"jaxplan {n}": lights for n in jp}},
            "neither peer reads traffic lights; the referee does not judge them (NGSIM Lankershim and SUMO maps "
            "have some)",
        ),
        row("goal rule", {"*": "CommonRoad's goal check on the car's centre"}, "the referee's"),
    ]
    moved = [r for r in equal if len({str(r[c]) for c in cols}) > 1]  # a value read from jaxplan that differs
    differ += moved
    equal = [{"setting": r["setting"], "value": r[cols[0]], "why": r["why"]} for r in equal if r not in moved]
    return {"columns": cols, "differ": differ, "equal": equal, "other_folders": extra}


def render_settings(table: dict) -> str:
    cols = table["columns"]
    esc = lambda v: str(v).replace("|", "/")  # noqa: E731
    lines = [
        "### Settings that differ between the planners",
        "",
        "| setting | " + " | ".join(cols) + " | why |",
        "| --- | " + " | ".join("---" for _ in cols) + " | --- |",
    ]
    lines += [
        f"| {r['setting']} | " + " | ".join(esc(r[c]) for c in cols) + f" | {esc(r['why'])} |" for r in table["differ"]
    ]
    lines += [
        "",
        f"### Settings that are equal ({', '.join(cols)})",
        "",
        "| setting | value | why |",
        "| --- | --- | --- |",
    ]
    lines += [f"| {r['setting']} | {esc(r['value'])} | {esc(r['why'])} |" for r in table["equal"]]
    if table.get("other_folders"):
        lines += [
            "",
            f"Also judged: {', '.join(table['other_folders'])} (drives of other planners: their settings "
            "are their planners'; the harness rows hold where they were driven by `jaxplan drive` with the same "
            "re-plan period and step cap).",
        ]
    return "\n".join(lines) + "\n"
