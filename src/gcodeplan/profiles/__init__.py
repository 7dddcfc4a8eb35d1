"""One-dimensional velocity profiles: the physics under the planner.

Python API (validates its arguments, raises ValueError naming the argument, InfeasibleProfile (a ValueError)
when no forward-only motion exists)::

    p = profiles.trapezoid(distance, v_max, a_max, v_start=0.0, v_end=0.0, decel=None)
    p = profiles.scurve(distance, v_max, a_max, j_max, v_start=0.0, v_end=0.0)
    p.duration, p.peak_velocity, p.phases, p.sample(t) -> (position, velocity, acceleration, jerk)
    profiles.trapezoid_durations(distance, v_max, a_max, v_start, v_end, decel=None)  # arrays in, durations
    profiles.scurve_durations(distance, v_max, a_max, j_max, v_start, v_end)          # out, NaN if infeasible

    profiles.timed_scurve(v_m, t_a, total_t=None)       # the notes' two-parabola S-curve
    profiles.equivalent_scurve(trapezoid_profile, jerk_fraction=1.0)   # same time, doubled peak accel
    profiles.via_points(positions, segment_times, blend_time=... | accel=...)  # parabolic fit, .deviation
    profiles.stopping_distance(v, decel), stopping_time, safe_spacing, braking_point(profile),
    profiles.line_throughput(v, body_length, decel), optimal_line_speed(body_length, decel, v_max=inf),
    profiles.stop_position(profile, t, decel)
    profiles.synchronize(distances, v_max, a_max, mode="interpolated" | "slew" | "sequential", j_max=None)

numba kernels for compiled callers (the planner's and the stepper's njit loops). Plain floats in, floats or
tuples of floats out, no allocation; NaN marks "no forward-only motion" or an invalid argument (no exceptions
inside compiled code). Units mm, s, mm/s, mm/s², mm/s³.

S-curves (seven-phase double-S, acceleration 0 at both ends; :mod:`.scurve` explains the solver):

``scurve_duration_kernel(distance, v_max, a_max, j_max, v_start, v_end) -> float``
    time-optimal duration, NaN if infeasible.
``scurve_phases_kernel(distance, v_max, a_max, j_max, v_start, v_end) -> (durations, jerks, peak_v)``
    ``durations`` and ``jerks`` are 7-tuples: +J, 0, -J (speed up to peak_v), 0 (cruise), -J, 0, +J (down to
    v_end). Phase 4 is the cruise. All NaN if infeasible.
``scurve_max_end_speed_kernel(distance, v_max, a_max, j_max, v_start) -> float``
    highest end speed reachable over `distance` from v_start (forward, a = 0 at both ends): the S-curve
    replacement of min(v_max, sqrt(v_start² + 2·a·d)) in the planner's forward pass.
``scurve_max_start_speed_kernel(distance, v_max, a_max, j_max, v_end) -> float``
    the same for the backward pass (highest start speed that can still slow to v_end), by time reversal.
``scurve_min_distance_kernel(v_max, a_max, j_max, v_start, v_end) -> float``
    least distance of a forward-only profile between these speeds.
``scurve_state_kernel(t, durations, jerks, v_start) -> (position, velocity, acceleration, jerk)``
    state at time t (clamped into the profile) of phases from scurve_phases_kernel, starting at position 0.
``scurve_position_kernel(t, distance, v_max, a_max, j_max, v_start, v_end) -> float``
    position at time t (solves the profile each call).
``ramp_time_kernel(dv, a_max, j_max)``, ``ramp_distance_kernel(v_from, v_to, a_max, j_max)``
    one fastest speed change with a = 0 at both ends.

Trapezoids (acceleration a_max while speeding up, `decel` while slowing down; pass a_max twice when equal):

``trapezoid_duration_kernel(distance, v_max, a_max, v_start, v_end, decel) -> float``
``trapezoid_phases_kernel(distance, v_max, a_max, v_start, v_end, decel) -> (accel_t, cruise_t, decel_t, peak_v)``
``trapezoid_max_end_speed_kernel(distance, v_max, a_max, v_start) -> float``
``trapezoid_state_kernel(t, accel_t, cruise_t, decel_t, v_start, a_max, decel) -> (position, velocity, accel)``

Feasibility slack: a distance short of the least needed distance by rounding only (a few ulps of the speeds,
see ``scurve.SPEED_ULPS``) counts as feasible, so an end speed from a max-speed kernel is always accepted back.
"""
from __future__ import annotations

from .braking import (  # noqa: F401
    BrakingPoint,
    braking_point,
    line_throughput,
    optimal_line_speed,
    safe_spacing,
    stop_position,
    stopping_distance,
    stopping_time,
)
from .core import PIECE_DTYPE, InfeasibleProfile, Profile  # noqa: F401
from .multiaxis import AxisProfiles, synchronize  # noqa: F401
from .constructions import ViaPointTrajectory, equivalent_scurve, parabolic_ramp_figures, timed_scurve, via_points  # noqa: F401
from .scurve import (  # noqa: F401
    scurve,
    scurve_durations,
    ramp_distance_kernel,
    ramp_time_kernel,
    ramp_times_kernel,
    scurve_duration_kernel,
    scurve_max_end_speed_kernel,
    scurve_max_start_speed_kernel,
    scurve_min_distance_kernel,
    scurve_phases_kernel,
    scurve_position_kernel,
    scurve_state_kernel,
)
from .trapezoid import (  # noqa: F401
    trapezoid,
    trapezoid_durations,
    trapezoid_duration_kernel,
    trapezoid_max_end_speed_kernel,
    trapezoid_phases_kernel,
    trapezoid_state_kernel,
)
