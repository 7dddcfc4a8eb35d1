"""The machine description: kinematics, limits, junction policy, dialect.

Units: mm, s, mm/s, mm/s², mm/s³. ``inf`` means "no limit".

The fields are the contract between the loaders (our TOML format, Klipper's
printer.cfg, presets) and the stages that use them (parser, planner, stepper).
Loaders live in :mod:`gcodeplan.config`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .schema import LIMITS_DTYPE

INF = math.inf

KINEMATICS = ("cartesian", "corexy", "corexz", "delta", "polar", "rotary_delta", "winch", "deltesian",
              "hybrid_corexy", "hybrid_corexz", "generic_cartesian")
FLAVORS = ("marlin", "klipper", "reprap", "grbl", "linuxcnc")
# Klipper's input shapers; the index is the code stored in LIMITS.shaper_type_x/_y (0 = none)
SHAPER_TYPES = ("none", "zv", "mzv", "zvd", "ei", "2hump_ei", "3hump_ei")
SHAPER_TYPE_CODES = {name: i for i, name in enumerate(SHAPER_TYPES)}
POLICIES = ("klipper", "junction-deviation", "classic-jerk", "blend", "exact-stop", "linuxcnc")
# firmware models: "generic" = planned by the junction policy alone; grbl 1.1 (planner/grbl.py) and Marlin
# (planner/marlin.py) run the firmware's own planner and step timing; Klipper and LinuxCNC are the klipper and
# linuxcnc policies (ports of Klipper's toolhead.py look-ahead and LinuxCNC's tp.c), so naming the firmware plans
# with that policy
FIRMWARES = ("generic", "grbl-1.1", "marlin-2.1.2", "marlin-bugfix", "klipper", "linuxcnc")
# the firmware models that plan with their own code (not a junction policy's): the pipeline names them
OWN_PLANNER_FIRMWARES = ("grbl-1.1", "marlin-2.1.2", "marlin-bugfix")
# the junction policies each firmware model plans with, the first its own: Marlin builds with CLASSIC_JERK or
# junction deviation (bugfix-2.1.x: classic jerk only, as modelled), grbl with junction deviation, Klipper and
# LinuxCNC with their ported planners. A run asked for another policy is planned by that policy alone.
FIRMWARE_POLICIES = {"marlin-2.1.2": ("classic-jerk", "junction-deviation"), "marlin-bugfix": ("classic-jerk",),
                     "grbl-1.1": ("junction-deviation",), "klipper": ("klipper",), "linuxcnc": ("linuxcnc",)}
# the firmware build each model was measured against (the shared reference runs): what the summary names
FIRMWARE_VERSIONS = {"klipper": "Klipper v0.13.0-730, git 84104bbbd", "linuxcnc": "LinuxCNC 2.9",
                     "marlin-2.1.2": "Marlin 2.1.2.4", "marlin-bugfix": "Marlin bugfix-2.1.x (2024-07-30)",
                     "grbl-1.1": "grbl 1.1h"}
ACCELERATION_PROFILES = ("trapezoid", "s-curve")
AXES = ("x", "y", "z", "e")


@dataclass
class Axis:
    max_velocity: float = INF     # mm/s (M203 / grbl $110..)
    max_accel: float = INF        # mm/s² (M201 / grbl $120..)
    jerk: float = 0.0             # mm/s classic jerk (M205 X/Y/Z/E); 0 = not set
    steps_per_mm: float = 80.0    # full steps × microsteps / rotation distance
    home: float = 0.0             # mm, position taken at G28 (modelled as instant)
    # mm, travel limits (Klipper's position_min/position_max): a move ending outside is an error
    # (gcode/reader.py); -inf/inf = no limit. Checked per axis (cartesian, corexy, corexz).
    position_min: float = -INF
    position_max: float = INF


@dataclass
class Machine:
    name: str = "generic"
    kinematics: str = "cartesian"
    # G-code dialect: G4 P unit, M204 meaning, whether M201/M203/M205 apply, G0 rapid rate
    flavor: str = "marlin"
    # firmware model (FIRMWARES): "generic" plans with junction_policy; a firmware's own planning and step timing
    # replace it otherwise (grbl-1.1: planner/grbl.py, marlin-2.1.2 and marlin-bugfix: planner/marlin.py);
    # "klipper" and "linuxcnc" plan with their policy (junction_policy must then be it, or left None)
    firmware: str = "generic"
    # a firmware model's speed ramps (ACCELERATION_PROFILES): "s-curve" = Marlin's S_CURVE_ACCELERATION
    acceleration_profile: str = "trapezoid"
    grbl_idle_lock_ms: float = 255.0     # grbl $1: ms the stepper ISR holds at every stop; 255 = keep enabled (none)
    grbl_laser_mode: int = 0             # grbl $32: 1 = laser mode (an S change on a motion line does not stop)

    # toolhead
    max_velocity: float = 300.0          # mm/s
    max_accel: float = 3000.0            # mm/s²; the accel used when M204 has not spoken
    accel_print: float | None = None     # mm/s² M204 P default (Marlin); None = max_accel
    accel_travel: float | None = None    # mm/s² M204 T default (Marlin); None = max_accel
    accel_retract: float | None = None   # mm/s² M204 R default (Marlin); None = max_accel
    rapid_velocity: float | None = None  # mm/s G0 rate on CNC flavors; None = max_velocity

    # junctions: the policy (POLICIES); None = the firmware's own ("linuxcnc" for firmware "linuxcnc"), else
    # "klipper". Always a name once the Machine is made.
    junction_policy: str | None = None
    square_corner_velocity: float = 5.0  # mm/s (Klipper)
    minimum_cruise_ratio: float = 0.5    # Klipper (max_accel_to_decel = max_accel·(1 − mcr))
    junction_deviation: float = 0.013    # mm (grbl $11, Marlin JUNCTION_DEVIATION_MM)
    blend_tolerance: float = 0.0         # mm, path tolerance for the blend policy (G64 P default)
    max_jerk: float = INF                # mm/s³ path jerk for S-curves; inf = trapezoids

    axes: dict[str, Axis] = field(default_factory=lambda: {a: Axis() for a in AXES})

    # extruder (Klipper's names)
    nozzle_diameter: float = 0.4
    filament_diameter: float = 1.75
    max_extrude_only_velocity: float = INF   # mm/s of filament
    max_extrude_only_accel: float = INF      # mm/s² of filament
    instantaneous_corner_velocity: float = 1.0  # mm/s
    max_extrude_ratio: float = INF           # mm filament per mm path; above is an error (Klipper)

    # arcs: chord tolerance (max sagitta, mm); when arc_resolution > 0 Klipper's rule is used instead
    arc_tolerance: float = 0.002
    arc_resolution: float = 0.0              # mm per segment (Klipper [gcode_arcs] resolution)
    # a Marlin build's ARC_SUPPORT settings (gcode.arcs_marlin.MarlinArcSettings, from its Configuration_adv.h);
    # None = Marlin 2.1.2's defaults with arc_resolution as MAX_ARC_SEGMENT_MM
    marlin_arcs: object = None
    # a Marlin build's switches that add G codes (MARLIN_BUILD_OPTIONS; its Configuration(_adv).h, or TOML
    # marlin_build = "INCH_MODE_SUPPORT CNC_WORKSPACE_PLANES"): names separated by blanks or commas, "" = none
    marlin_build: str = ""
    # a Marlin build's BLOCK_BUFFER_SIZE (Configuration_adv.h; a power of 2): the planner ring of the Marlin
    # models (one slot always free); 16 is Marlin's default, 32 or 64 are common on 32-bit boards
    marlin_block_buffer: int = 16

    # firmware retraction (G10/G11)
    retract_length: float = 0.0              # mm
    retract_speed: float = 20.0              # mm/s
    unretract_extra_length: float = 0.0      # mm
    unretract_speed: float = 10.0            # mm/s

    # time not spent moving
    homing_time: float = 0.0                 # s per G28 (reported with the waits)
    heat_wait_time: float = 0.0              # s per M109/M190 (reported with the waits)
    tool_change_time: float = 0.0            # s per T<n> / M6 that changes the tool (a wait named tool_change)
    filament_change_time: float = 0.0        # s per M600 filament change (a wait named M600)
    start_time: float = 0.0                  # s before the first line: a fixed start offset (a wait named start)
    macros: dict[str, float] = field(default_factory=dict)   # s per command name (PRINT_START = 240)

    max_step_rate: float = INF               # steps/s per stepper: above it the stepper warns

    # LinuxCNC trajectory-planner settings (planner.linuxcnc.LinuxcncSettings; None = LinuxCNC 2.9's defaults)
    linuxcnc: object = None

    # step stream (the planner ignores these): Klipper's pressure advance and input shaper
    pressure_advance: float = 0.0            # s (Klipper [extruder] pressure_advance); 0 = off
    pressure_advance_smooth_time: float = 0.040  # s (Klipper's default)
    shaper_type_x: str = "mzv"               # zv, mzv, zvd, ei, 2hump_ei, 3hump_ei (Klipper [input_shaper])
    shaper_type_y: str = "mzv"
    shaper_freq_x: float = 0.0               # Hz, 0 = no shaping on X
    shaper_freq_y: float = 0.0               # Hz, 0 = no shaping on Y
    damping_ratio_x: float = 0.1
    damping_ratio_y: float = 0.1

    # linear delta (kinematics "delta", Klipper's delta.py): towers a, b, c; see kinematics/delta.py
    delta_radius: float = 0.0                # mm, tower circle radius (Klipper [printer] delta_radius); required
    print_radius: float | None = None        # mm, reachable XY radius; None = delta_radius
    minimum_z_position: float = 0.0          # mm, lowest Z a move may end at
    delta_arm_length: tuple[float, float, float] = (0.0, 0.0, 0.0)           # mm per tower; required
    delta_angle: tuple[float, float, float] = (210.0, 330.0, 90.0)           # degrees per tower
    # mm, nozzle Z at X = Y = 0 with that tower's carriage at its endstop
    delta_position_endstop: tuple[float, float, float] = (0.0, 0.0, 0.0)
    delta_steps_per_mm: tuple[float, float, float] = (80.0, 80.0, 80.0)      # steps per mm of carriage travel

    # a plug-in kinematics' own settings (gcodeplan.kinematics.plugin; e.g. polar's max_angular_velocity, a winch's
    # anchors): Klipper's option names, mm / rad / mm/s; a machine file's [kinematics_params] table
    kinematics_params: dict = field(default_factory=dict)

    # True for the default machine (no --machine / --flavor / --klipper-config / --linuxcnc-ini; machine=None in
    # the API): a file that is clearly a CNC program is then read with a CNC flavor (gcode/dialect.py). Not a
    # machine property: equal machines may differ in it.
    auto_flavor: bool = field(default=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.junction_policy is None:
            self.junction_policy = policy_of_firmware(self.firmware) or "klipper"
        problem = firmware_policy_conflict(self.firmware, self.junction_policy)
        if problem is not None:
            from .errors import ConfigError

            raise ConfigError(problem)

    # ------------------------------------------------------------------ derived
    def limits_row(self) -> np.ndarray:
        """Row 0 of the LIMITS table: the limits in force before the G-code changes any."""
        row = np.zeros(1, dtype=LIMITS_DTYPE)
        r = row[0]
        r["max_v"] = self.max_velocity
        r["max_a"] = self.max_accel
        r["scv"] = self.square_corner_velocity
        r["mcr"] = self.minimum_cruise_ratio
        r["junction_dev"] = self.junction_deviation
        for a in AXES:
            ax = self.axes[a]
            r["jerk_" + a] = ax.jerk
            r["axis_v_" + a] = ax.max_velocity
            r["axis_a_" + a] = ax.max_accel
        r["extrude_only_v"] = self.max_extrude_only_velocity
        r["extrude_only_a"] = self.max_extrude_only_accel
        r["icv"] = self.instantaneous_corner_velocity
        r["min_feed_v"] = 0.0
        r["min_travel_v"] = 0.0
        r["max_jerk"] = self.max_jerk
        r["pa_k"] = self.pressure_advance
        r["pa_smooth_t"] = self.pressure_advance_smooth_time
        for a in ("x", "y"):
            r["shaper_type_" + a] = SHAPER_TYPE_CODES.get(getattr(self, "shaper_type_" + a), -1)
            r["shaper_freq_" + a] = getattr(self, "shaper_freq_" + a)
            r["damping_" + a] = getattr(self, "damping_ratio_" + a)
        if self.kinematics == "delta":
            from .kinematics.delta import DeltaGeometry

            g = DeltaGeometry.from_machine(self)
            r["delta_slow_xy2"], r["delta_very_slow_xy2"] = g.slow_xy2, g.very_slow_xy2
            r["delta_slow_v"], r["delta_slow_a"] = self.max_velocity, self.max_accel
        return row

    @property
    def is_cnc(self) -> bool:
        return self.flavor in ("grbl", "linuxcnc")


def policy_of_firmware(firmware: str) -> str | None:
    """The junction policy that *is* ``firmware``'s planner (``klipper``, ``linuxcnc``), None for the others (a
    generic machine, or a firmware model planning with its own code)."""
    if firmware in OWN_PLANNER_FIRMWARES:
        return None
    own = FIRMWARE_POLICIES.get(firmware)
    return own[0] if own else None


def firmware_policy_conflict(firmware: str, policy: str) -> str | None:
    """The problem with a machine of ``firmware`` naming junction ``policy`` (None = none): Klipper and LinuxCNC
    plan with their own policy only, so another one named beside them is a contradiction, not a choice."""
    own = policy_of_firmware(firmware)
    if own is None or policy == own:
        return None
    return (f"firmware {firmware!r} plans with the {own!r} junction policy, but the machine names policy "
            f"{policy!r}: name one of them (firmware = \"generic\" plans with the policy alone)")


def firmware_model(machine, policy: str | None = None) -> str:
    """The firmware model that plans ``machine`` with junction ``policy`` (None = the machine's): its firmware
    when that firmware plans with the policy (:data:`FIRMWARE_POLICIES`), else ``"generic"`` (the policy alone:
    a run asked for a policy the firmware does not have is planned by that policy, as the policy runs)."""
    firmware = getattr(machine, "firmware", "generic")
    policy = policy or machine.junction_policy
    return firmware if policy in FIRMWARE_POLICIES.get(firmware, ()) else "generic"


def firmware_version(firmware: str) -> str:
    """The firmware build a model reproduces, as the summary names it (``"Marlin 2.1.2.4"``); "" for generic."""
    return FIRMWARE_VERSIONS.get(firmware, "")


def with_firmware(machine: Machine, firmware: str) -> Machine:
    """A copy of ``machine`` run by ``firmware`` (``--firmware``, ``load_machine(firmware=)``): Klipper and
    LinuxCNC bring their policy along (they are it), the others keep the machine's policy."""
    from dataclasses import replace

    return replace(machine, firmware=firmware, junction_policy=policy_of_firmware(firmware) or machine.junction_policy)


def planned_by(machine, run_policy: str, jerk: float | None = None) -> str:
    """The firmware model a run of ``machine`` was planned by, "" when by the junction policy alone.
    ``run_policy``: the run's name for how it planned (pipeline.Drive.policy: the policy, or the firmware model
    that replaced it); ``jerk`` (mm/s³, the run's --jerk): S-curves, which neither Klipper nor LinuxCNC plans, so
    such a run is the policy's alone (the firmware models with their own planner refuse a jerk)."""
    if run_policy in OWN_PLANNER_FIRMWARES:
        return run_policy
    if jerk is not None or math.isfinite(machine.max_jerk):
        return ""
    model = firmware_model(machine, run_policy)
    return "" if model == "generic" else model
