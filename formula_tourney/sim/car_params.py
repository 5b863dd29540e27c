"""Parameters of the simulated car, shared by the physics, the speed profile and the bots.

One pydantic model so that the car's grip, aero and power are defined once: the quasi-steady-
state lap time (the reference limit) must use exactly the numbers the simulator integrates.
Defaults are a TORCS-like single-seater: ~1150 kg, mu ~1.6, top speed near 300 km/h.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

GRAVITY_MPS2 = 9.81


class CarParams(BaseModel):
    """Physical constants of one car. Units are in the names."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    mass_kg: float = Field(1150.0, gt=0, description="Mass with driver and fuel.")
    yaw_inertia_kgm2: float = Field(1900.0, gt=0, description="Yaw moment of inertia.")
    cg_to_front_m: float = Field(1.25, gt=0, description="Centre of gravity to front axle.")
    cg_to_rear_m: float = Field(1.35, gt=0, description="Centre of gravity to rear axle.")
    cg_height_m: float = Field(0.35, ge=0, description="CG height (load transfer).")
    track_width_m: float = Field(1.6, gt=0, description="Distance between left and right wheels.")
    car_length_m: float = Field(4.5, gt=0, description="Body length (rendering, wall contact).")
    car_width_m: float = Field(1.9, gt=0, description="Body width (wall contact).")
    mu: float = Field(1.6, gt=0, description="Tyre friction coefficient on asphalt.")
    mu_grass: float = Field(0.7, gt=0, description="Tyre friction coefficient on grass.")
    grass_drag_n_per_mps: float = Field(
        120.0, ge=0, description="Extra rolling drag on grass per m/s of speed."
    )
    cornering_stiffness_front_n_per_rad: float = Field(
        95000.0, gt=0, description="Front axle cornering stiffness (Fiala tyre)."
    )
    cornering_stiffness_rear_n_per_rad: float = Field(
        110000.0, gt=0, description="Rear axle cornering stiffness (Fiala tyre)."
    )
    drag_coef_n_per_mps2: float = Field(
        0.45, ge=0, description="0.5 * rho * Cd * A: drag force = coef * v^2."
    )
    downforce_coef_n_per_mps2: float = Field(
        1.2, ge=0, description="0.5 * rho * Cl * A: downforce = coef * v^2."
    )
    rolling_resistance: float = Field(0.015, ge=0, description="Rolling resistance coefficient.")
    wheel_radius_m: float = Field(0.33, gt=0, description="Rolling radius of all wheels.")
    engine_rpm_points: tuple[float, ...] = Field(
        (1000.0, 3000.0, 5000.0, 6500.0, 7500.0, 8500.0), description="Torque curve rpm points."
    )
    engine_torque_points_nm: tuple[float, ...] = Field(
        (220.0, 320.0, 390.0, 410.0, 395.0, 340.0), description="Torque at those rpm points."
    )
    idle_rpm: float = Field(1000.0, gt=0, description="Engine idle speed.")
    redline_rpm: float = Field(8500.0, gt=0, description="Fuel cut; the gearbox shifts up below.")
    gear_ratios: tuple[float, ...] = Field(
        (3.10, 2.25, 1.75, 1.40, 1.15, 0.96), description="Forward gear ratios."
    )
    final_drive: float = Field(3.4, gt=0, description="Differential ratio.")
    drivetrain_efficiency: float = Field(0.9, gt=0, le=1, description="Engine to wheel losses.")
    upshift_rpm: float = Field(8000.0, gt=0, description="Automatic gearbox shifts up here.")
    downshift_rpm: float = Field(4000.0, gt=0, description="Automatic gearbox shifts down here.")
    max_brake_force_n: float = Field(
        30000.0, gt=0, description="Total brake force at full pedal, before the grip limit."
    )
    brake_bias_front: float = Field(0.6, gt=0, lt=1, description="Front share of brake force.")
    max_steer_rad: float = Field(0.366, gt=0, description="Wheel angle at full lock (21 deg).")
    wall_damage_per_mps: float = Field(
        100.0, ge=0, description="Damage points per m/s of impact speed into a wall."
    )
    wall_restitution: float = Field(
        0.2, ge=0, le=1, description="Share of normal speed kept (reversed) after a wall hit."
    )

    @property
    def wheelbase_m(self) -> float:
        return self.cg_to_front_m + self.cg_to_rear_m

    def fingerprint(self) -> str:
        """Short hash of all parameters: caches of lines and limits are keyed by it."""
        blob = json.dumps(self.model_dump(), sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:12]

    def engine_torque_nm(self, rpm: np.ndarray | float) -> np.ndarray:
        rpm = np.asarray(rpm, dtype=float)
        torque = np.interp(rpm, self.engine_rpm_points, self.engine_torque_points_nm)
        return np.where(rpm > self.redline_rpm, 0.0, torque)

    def engine_rpm(self, speed_mps: np.ndarray | float, gear_ratio: float) -> np.ndarray:
        wheel_rad_s = np.asarray(speed_mps, dtype=float) / self.wheel_radius_m
        return np.maximum(wheel_rad_s * gear_ratio * self.final_drive * 60.0 / (2 * np.pi),
                          self.idle_rpm)

    def max_drive_force_n(self, speed_mps: np.ndarray | float) -> np.ndarray:
        """Largest tractive force over all gears at a speed (the ideal gearbox), before grip."""
        speed = np.asarray(speed_mps, dtype=float)
        best = np.zeros_like(speed)
        for ratio in self.gear_ratios:
            torque = self.engine_torque_nm(self.engine_rpm(speed, ratio))
            force = torque * ratio * self.final_drive * self.drivetrain_efficiency
            best = np.maximum(best, force / self.wheel_radius_m)
        return best

    def drag_force_n(self, speed_mps: np.ndarray | float) -> np.ndarray:
        return self.drag_coef_n_per_mps2 * np.asarray(speed_mps, dtype=float) ** 2

    def downforce_n(self, speed_mps: np.ndarray | float) -> np.ndarray:
        return self.downforce_coef_n_per_mps2 * np.asarray(speed_mps, dtype=float) ** 2

    def normal_force_n(self, speed_mps: np.ndarray | float) -> np.ndarray:
        return self.mass_kg * GRAVITY_MPS2 + self.downforce_n(speed_mps)
