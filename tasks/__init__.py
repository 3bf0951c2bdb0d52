"""Tasks of policy-composer. Importing this package registers the environments with Gymnasium/ManiSkill:
``GearAssembly-v1`` (ManiSkill, bimanual gear assembly)."""

from tasks.gear_assembly import CAMERA_NAMES, GearAssemblyEnv  # noqa: F401  (registers GearAssembly-v1)
