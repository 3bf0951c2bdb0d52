"""A Panda whose visual meshes are decimated, so three cameras render fast on a CPU.

The stock Panda visual meshes carry about 135k triangles per arm, and on lavapipe (Mesa's CPU Vulkan
driver) rendering cost is geometry: two stock arms with three 128x128 cameras run at about 6 env
steps/s. Decimating every visual mesh about 10x (after merging duplicated vertices, keeping each
sub-mesh's material) keeps the look at 128x128 and renders several times faster. Collision meshes,
kinematics and controllers are the stock Panda's.

The decimated meshes are made once and cached under ``$POLICY_COMPOSER_CACHE`` (default
``~/.cache/policy-composer``), keyed by the ManiSkill version and the decimation ratio.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import mani_skill
from mani_skill import PACKAGE_ASSET_DIR
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.panda import Panda

DECIMATION = 0.1  # fraction of triangles kept per visual sub-mesh
_PANDA_DIR = Path(PACKAGE_ASSET_DIR) / "robots" / "panda"
_URDF_NAME = "panda_v2.urdf"


def cache_dir() -> Path:
    """Where derived assets (decimated meshes) live; override with POLICY_COMPOSER_CACHE."""
    return Path(os.environ.get("POLICY_COMPOSER_CACHE", Path.home() / ".cache" / "policy-composer"))


def _decimate_glb(src: Path, dst: Path, ratio: float) -> None:
    import fast_simplification
    import trimesh

    scene = trimesh.load(src, force="scene")
    for name, mesh in list(scene.geometry.items()):
        mesh.merge_vertices(merge_tex=True, merge_norm=True)  # GLB meshes are triangle soups
        target = max(int(len(mesh.faces) * ratio), 32)
        if len(mesh.faces) <= target:
            continue
        points, faces = fast_simplification.simplify(
            mesh.vertices.astype("float32"), mesh.faces, target_reduction=1.0 - target / len(mesh.faces)
        )
        material = getattr(mesh.visual, "material", None)
        simplified = trimesh.Trimesh(points, faces, process=False)
        if material is not None:
            simplified.visual = trimesh.visual.TextureVisuals(material=material)
        scene.geometry[name] = simplified
    tmp = dst.with_suffix(".tmp.glb")
    scene.export(tmp)
    tmp.replace(dst)  # atomic: a crash never leaves a half-written mesh in the cache


def decimated_panda_urdf(ratio: float = DECIMATION) -> Path:
    """Path to a Panda URDF with decimated visual meshes, building the cache on first use."""
    root = cache_dir() / f"panda_light-ms{mani_skill.__version__}-r{ratio:g}"
    urdf = root / _URDF_NAME
    if urdf.exists():
        return urdf
    visual_src = _PANDA_DIR / "franka_description" / "meshes" / "visual"
    visual_dst = root / "franka_description" / "meshes" / "visual"
    visual_dst.mkdir(parents=True, exist_ok=True)
    collision_link = root / "franka_description" / "meshes" / "collision"
    if not collision_link.exists():
        collision_link.symlink_to(_PANDA_DIR / "franka_description" / "meshes" / "collision")
    for glb in sorted(visual_src.glob("*.glb")):
        if not (visual_dst / glb.name).exists():
            _decimate_glb(glb, visual_dst / glb.name, ratio)
    srdf = _PANDA_DIR / _URDF_NAME.replace(".urdf", ".srdf")
    if srdf.exists():
        shutil.copy(srdf, root / srdf.name)
    tmp = urdf.with_suffix(".tmp")
    shutil.copy(_PANDA_DIR / _URDF_NAME, tmp)
    tmp.replace(urdf)  # written last: its presence means the cache is complete
    return urdf


@register_agent()
class PandaLight(Panda):
    """The stock ManiSkill Panda (same joints, controllers, collisions) with decimated visual meshes."""

    uid = "panda_light"

    @property
    def urdf_path(self) -> str:  # type: ignore[override]
        return str(decimated_panda_urdf())
