"""Tasks of policy-composer: ``GearAssembly-v1`` (ManiSkill, bimanual gear assembly; importing
``policy_composer.tasks.gear_assembly`` registers it), its scripted expert, and the random-walk MDP.
``policy_composer.tasks.spec`` names its cameras, state and action without importing the simulator."""
