"""What the library reads of PegInsertionSide-v1's state: the subtask predicates its recordings are labelled with, the
strict success beside ManiSkill's (ManiSkill issue 1391), and the stage. Privileged: labels, the oracle, the scorer."""

from __future__ import annotations

import torch

HOLE_ENTRY = -0.015  # ManiSkill's bound: the peg's head this far short of the hole's centre plane, along its axis (m)
PRE_INSERTION_DISTANCE = 0.05  # the peg's head at most this far in front of the box's near face (m)
ALIGN_TOL_DEG = 10.0  # the peg's axis within this of the hole's at the pre-insertion pose


def box_half_depth(env) -> torch.Tensor:
    """(B,) half the box's depth along the hole's axis: ManiSkill builds the box as deep as the peg is long."""
    return env.unwrapped.peg_half_sizes[:, 0]


def _not_past(env, inserted: torch.Tensor, head: torch.Tensor) -> torch.Tensor:
    """ManiSkill's `has_peg_inserted()` (inserted, the peg's head in the hole's frame, x into the box), with the head
    no farther in than the box's far face."""
    return inserted & (head[:, 0] <= box_half_depth(env))


def stage_of(flags: dict[str, torch.Tensor]) -> torch.Tensor:
    """(B,) 0 pick, 1 move, 2 insert, 3 done, from the predicates."""
    return torch.where(flags["peg_seated"], 3, torch.where(flags["peg_at_hole"] | flags["peg_inserted"], 2,
                                                           flags["peg_grasped"].long()))


def strict_success(env) -> torch.Tensor:
    """(B,) bool: ManiSkill's success, with the peg's head no farther in than the box's far face."""
    return _not_past(env, *env.unwrapped.has_peg_inserted())


def predicates(env) -> dict[str, torch.Tensor]:
    """Each of PREDICATES from the simulator's truth, (B,) bool: privileged, for labels and the oracle."""
    u = env.unwrapped
    inserted, head = u.has_peg_inserted()
    radius = u.box_hole_radii
    peg_axis = u.peg.pose.to_transformation_matrix()[:, :3, 0]
    hole_axis = u.box_hole_pose.to_transformation_matrix()[:, :3, 0]
    aligned = (peg_axis * hole_axis).sum(-1) > torch.cos(torch.deg2rad(torch.tensor(ALIGN_TOL_DEG)))
    on_axis = torch.linalg.norm(head[:, 1:], dim=-1) < radius
    # At the hole: in front of the box's near face, or part-way in short of ManiSkill's bound (an insertion that
    # stopped there is the insertion's to go on with, not the carry's).
    at_hole = ~inserted & (head[:, 0] > -box_half_depth(u) - PRE_INSERTION_DISTANCE)
    grasped = u.agent.is_grasping(u.peg)
    return {"peg_grasped": grasped, "peg_at_hole": grasped & aligned & on_axis & at_hole,
            "peg_inserted": inserted, "peg_seated": _not_past(u, inserted, head)}
