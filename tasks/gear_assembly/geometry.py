"""Geometry of the compound gear and the peg module, built from boxes and cylinders.

PhysX has no concave shapes for dynamic bodies, so the gear's hole is made real by building each
toothed ring from boxes placed around the axis: the hole stays empty and a peg can pass through it.
Frames: the gear's origin is the centre of its bottom face, z along its axis; the peg module's origin
is the top face of the base plate at the peg's foot, z along the peg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien
from transforms3d.euler import euler2quat

from policy_composer.tasks.gear_assembly.spec import CLEARANCE_MM

BRASS = [0.80, 0.62, 0.22, 1.0]
COPPER = [0.85, 0.40, 0.15, 1.0]
STEEL = [0.70, 0.72, 0.75, 1.0]
PLATE = [0.20, 0.22, 0.28, 1.0]


@dataclass(frozen=True)
class GearSpec:
    """Dimensions in metres. The hole radius is the peg radius plus the radial clearance."""

    peg_radius: float = 0.006
    peg_height: float = 0.04
    clearance: float = 0.002
    ring_outer: float = 0.026  # large gear, body radius (teeth stand outside it)
    ring_thickness: float = 0.010
    ring_teeth: int = 18
    top_outer: float = 0.014  # small gear stacked on the large one
    top_thickness: float = 0.012
    top_teeth: int = 12
    segments: int = 16  # boxes per ring around the hole
    plate_half_size: tuple[float, float, float] = (0.085, 0.024, 0.005)
    peg_offset: float = 0.11  # peg axis distance from where the hand grips the plate

    def __post_init__(self) -> None:
        low, high = (mm / 1000 for mm in CLEARANCE_MM)
        if not low <= self.clearance <= high:
            raise ValueError(f"clearance={self.clearance} m: choose a radial clearance between {low} and {high} m")

    @property
    def hole_radius(self) -> float:
        return self.peg_radius + self.clearance

    @property
    def grasp_height(self) -> float:
        """The TCP above the gear's bottom in the nominal grasp: the fingers pinch the small gear's teeth."""
        return self.ring_thickness + 0.7 * self.top_thickness

    @property
    def height(self) -> float:
        return self.ring_thickness + self.top_thickness

    @property
    def top_tip_radius(self) -> float:
        return self.top_outer + 0.005

    @property
    def outer_radius(self) -> float:
        return self.ring_outer + 0.006


def _add_box(builder: sapien.ActorBuilder, p, yaw: float, half_size, color, material=None) -> None:
    pose = sapien.Pose(p=p, q=euler2quat(0, 0, yaw))
    builder.add_box_collision(pose=pose, half_size=half_size, material=material)
    builder.add_box_visual(pose=pose, half_size=half_size, material=sapien.render.RenderMaterial(base_color=color))


def _add_toothed_ring(builder, r_in, r_out, z0, thickness, n_segments, n_teeth, tooth_depth, color, material):
    """A ring of boxes (the hole stays empty) with box teeth on its rim."""
    hz = thickness / 2
    seg_half_len = r_out * np.tan(np.pi / n_segments) + 1e-4
    for k in range(n_segments):
        a = 2 * np.pi * k / n_segments
        r = (r_in + r_out) / 2
        _add_box(builder, [r * np.cos(a), r * np.sin(a), z0 + hz], a,
                 [(r_out - r_in) / 2, seg_half_len, hz], color, material)
    tooth_half_width = 0.45 * np.pi * r_out / n_teeth
    for k in range(n_teeth):
        a = 2 * np.pi * (k + 0.5) / n_teeth
        r = r_out + tooth_depth / 2 - 5e-4
        _add_box(builder, [r * np.cos(a), r * np.sin(a), z0 + hz], a,
                 [tooth_depth / 2, tooth_half_width, hz], color, material)


def build_gear(scene, spec: GearSpec, name: str = "gear"):
    """The compound gear: a toothed ring with a through hole and a smaller toothed gear on top."""
    builder = scene.create_actor_builder()
    material = sapien.pysapien.physx.PhysxMaterial(static_friction=0.6, dynamic_friction=0.5, restitution=0.0)
    _add_toothed_ring(builder, spec.hole_radius, spec.ring_outer, 0.0, spec.ring_thickness,
                      spec.segments, spec.ring_teeth, spec.outer_radius - spec.ring_outer, BRASS, material)
    _add_toothed_ring(builder, spec.hole_radius, spec.top_outer, spec.ring_thickness, spec.top_thickness,
                      spec.segments, spec.top_teeth, spec.top_tip_radius - spec.top_outer, COPPER, material)
    builder.initial_pose = sapien.Pose(p=[0.3, -0.3, 0.1])
    return builder.build(name=name)


def build_peg_module(scene, spec: GearSpec, name: str = "peg_module"):
    """Base plate with a vertical peg; kinematic, carried by the right hand (see GearAssembly-v1)."""
    builder = scene.create_actor_builder()
    hx, hy, hz = spec.plate_half_size
    # The plate reaches from behind the grip point to beyond the peg; origin = plate top at the peg foot.
    plate_center = [-spec.peg_offset - 0.03 + hx, 0.0, -hz]
    builder.add_box_collision(pose=sapien.Pose(p=plate_center), half_size=[hx, hy, hz])
    builder.add_box_visual(pose=sapien.Pose(p=plate_center), half_size=[hx, hy, hz],
                           material=sapien.render.RenderMaterial(base_color=PLATE))
    # SAPIEN cylinders lie along x: turn it to stand along z.
    peg_pose = sapien.Pose(p=[0, 0, spec.peg_height / 2], q=euler2quat(0, -np.pi / 2, 0))
    builder.add_cylinder_collision(pose=peg_pose, radius=spec.peg_radius, half_length=spec.peg_height / 2)
    builder.add_cylinder_visual(pose=peg_pose, radius=spec.peg_radius, half_length=spec.peg_height / 2,
                                material=sapien.render.RenderMaterial(base_color=STEEL))
    builder.initial_pose = sapien.Pose(p=[0.3, 0.3, 0.3])
    return builder.build_kinematic(name=name)
