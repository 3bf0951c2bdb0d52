"""A Panda whose visual meshes are decimated, so three cameras render fast on a CPU.

The stock Panda visual meshes carry about 135k triangles per arm, and on lavapipe (Mesa's CPU Vulkan
driver) rendering cost is geometry: two stock arms with three 128x128 cameras run at about 6 env
steps/s. Decimating every visual mesh about 10x (after merging duplicated vertices, keeping each
sub-mesh's material) keeps the look at 128x128 and renders several times faster. Collision meshes,
kinematics and controllers are the stock Panda's.

The decimated meshes are made once and cached under ``$POLICY_COMPOSER_CACHE`` (default
``~/.cache/policy-composer``), keyed by the cache's layout, the ManiSkill version and the decimation ratio.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import fast_simplification
import mani_skill
import trimesh
from filelock import FileLock
from mani_skill import PACKAGE_ASSET_DIR
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.panda import Panda

DECIMATION = 0.1  # fraction of triangles kept per visual sub-mesh
_PANDA_DIR = Path(PACKAGE_ASSET_DIR) / "robots" / "panda"
_URDF_NAME = "panda_v2.urdf"
CACHE_LAYOUT = "v2"  # in the cache folder's name: a cache of another layout is not read


def cache_dir() -> Path:
    """Where derived assets (decimated meshes) live; override with POLICY_COMPOSER_CACHE."""
    return Path(os.environ.get("POLICY_COMPOSER_CACHE", Path.home() / ".cache" / "policy-composer"))


def _decimate_glb(src: Path, dst: Path, ratio: float) -> None:
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
    scene.export(dst)


def decimated_panda_urdf(ratio: float = DECIMATION) -> Path:
    """Path to a Panda URDF with decimated visual meshes, building the cache on first use. Processes that start
    together on a fresh machine (an episode loop's workers) build it once: the others wait on its lock."""
    root = cache_dir() / f"panda_light-{CACHE_LAYOUT}-ms{mani_skill.__version__}-r{ratio:g}"
    urdf = root / _URDF_NAME
    if urdf.exists():
        return urdf
    root.parent.mkdir(parents=True, exist_ok=True)
    with FileLock(root.parent / f"{root.name}.lock"):
        if not urdf.exists():
            _build(root, ratio)
    return urdf


def _build(root: Path, ratio: float) -> None:
    """The decimated Panda's folder: built aside and renamed into place, so a killed build leaves none. It holds a
    copy of the stock collision meshes, not a link into one installation's ManiSkill, which another may outlive."""
    building = root.with_name(f"{root.name}.building")
    shutil.rmtree(building, ignore_errors=True)
    stock, meshes = (folder / "franka_description" / "meshes" for folder in (_PANDA_DIR, building))
    (meshes / "visual").mkdir(parents=True)
    shutil.copytree(stock / "collision", meshes / "collision")
    for glb in sorted((stock / "visual").glob("*.glb")):
        _decimate_glb(glb, meshes / "visual" / glb.name, ratio)
    for name in (_URDF_NAME, _URDF_NAME.replace(".urdf", ".srdf")):
        if (_PANDA_DIR / name).exists():
            shutil.copy(_PANDA_DIR / name, building / name)
    building.rename(root)


@register_agent()
class PandaLight(Panda):
    """The stock ManiSkill Panda (same joints, controllers, collisions) with decimated visual meshes."""

    uid = "panda_light"

    @property
    def urdf_path(self) -> str:  # type: ignore[override]
        return str(decimated_panda_urdf())
