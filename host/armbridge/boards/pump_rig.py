"""The syringe-pump rig's nominal physics: what one channel of the soft arm's hardware is.

Per joint a 12 V linear motor on an L298 pushes the plunger of a 100 mL
syringe tubed to one pneumatic joint (WJRRT paper, section V-B/C). The numbers
are ours (the paper gives none; docs/emulator.md, "Syringe-pump board in
simavr"): the planner times its moves with them (planning/soft/pump_timing.py)
and the emulator's plant is built from them (emulator/pump_plant.py), so both
read one description of the rig.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PumpParams:
    """Physical numbers of one syringe channel (all joints share them but their range).

    travel_mm   100    plunger travel of a 100 mL syringe
    area_mm2    1000   plunger area: 1 mL per mm (a ~36 mm bore)
    v_motor     20     plunger speed at full duty, mm/s (a 12 V linear motor, no load)
    tau_motor   0.02   motor speed lag, s
    dead_duty   0.05   duty below which the motor does not move (static friction)
    switch_mm   0.5    an end stop closes this close to either end of travel
    x0_mm       2.0    plunger position at power on (just off the retracted stop)
    v_tube_ml   5      tubing between syringe and joint
    v_joint_ml  10     the straight joint's air volume
    k_vol_ml    20     air the joint takes in per radian of bend
    p0_kpa      101.325 atmosphere
    p_open_kpa  12     a closed (straight) joint opens at this gauge pressure
    p_hold_kpa  5      the open branch reaches theta = 0 here
    p_full_kpa  30     the open branch reaches the joint's range here
    tau_inflate 0.05   bend time constant while inflating, s (abrupt)
    tau_deflate 0.40   bend time constant while deflating, s (smooth)
    sigma_mv    3.0    bend-sensor noise, mV (0.6 of a 10-bit LSB)
    max_dt      0.001  longest integration sub-step, s
    """

    travel_mm: float = 100.0
    area_mm2: float = 1000.0
    v_motor: float = 20.0
    tau_motor: float = 0.02
    dead_duty: float = 0.05
    switch_mm: float = 0.5
    x0_mm: float = 2.0
    v_tube_ml: float = 5.0
    v_joint_ml: float = 10.0
    k_vol_ml: float = 20.0
    p0_kpa: float = 101.325
    p_open_kpa: float = 12.0
    p_hold_kpa: float = 5.0
    p_full_kpa: float = 30.0
    tau_inflate: float = 0.05
    tau_deflate: float = 0.40
    sigma_mv: float = 3.0
    max_dt: float = 0.001

    @property
    def v_rest_ml(self) -> float:
        """Air at atmospheric pressure with the plunger retracted and the joint straight."""
        return self.travel_mm * self.area_mm2 / 1000.0 + self.v_tube_ml + self.v_joint_ml
