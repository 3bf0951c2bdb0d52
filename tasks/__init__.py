"""Tasks of policy-composer: ``GearAssembly-v1`` (this project's ManiSkill task, `gear_assembly`), ManiSkill's own
``PegInsertionSide-v1`` read by a task adapter (`peg_insertion_side`), and the random-walk MDP; the Panda the
controllers drive (`panda`, `panda_light`).

Importing this package registers ``GearAssembly-v1`` with gymnasium, as ``import mani_skill.envs`` registers
ManiSkill's tasks; the simulator itself is imported when the first env is made, not here (it costs seconds).
"""

from policy_composer.tasks import gear_assembly  # noqa: F401  (registers GearAssembly-v1)
