"""The decimated Panda: built once into the cache, far fewer triangles, same materials."""

import multiprocessing
import shutil
import time
from pathlib import Path

import trimesh

from policy_composer.tasks import panda_light


def test_decimated_meshes_are_cached_smaller_and_keep_their_materials(tmp_path, monkeypatch):
    monkeypatch.setenv("POLICY_COMPOSER_CACHE", str(tmp_path))
    urdf = panda_light.decimated_panda_urdf()
    assert urdf.exists() and urdf.is_relative_to(tmp_path)
    stock_dir = panda_light._PANDA_DIR / "franka_description" / "meshes" / "visual"
    light_dir = urdf.parent / "franka_description" / "meshes" / "visual"
    stock_faces = light_faces = 0
    for glb in sorted(stock_dir.glob("*.glb")):
        stock, light = trimesh.load(glb, force="scene"), trimesh.load(light_dir / glb.name, force="scene")
        stock_faces += sum(len(g.faces) for g in stock.geometry.values())
        light_faces += sum(len(g.faces) for g in light.geometry.values())
        def colors(scene):
            return sorted(tuple(g.visual.material.baseColorFactor) for g in scene.geometry.values())

        assert colors(light) == colors(stock), glb.name
        # Decimation keeps the shape: bounding boxes agree within 5 mm.
        assert abs(light.bounds - stock.bounds).max() < 0.005, glb.name
    assert light_faces < stock_faces / 5
    mtime = urdf.stat().st_mtime
    assert panda_light.decimated_panda_urdf() == urdf and urdf.stat().st_mtime == mtime  # reused, not rebuilt


def _build_in_a_worker(start, log):
    start.wait()
    log.put(str(panda_light.decimated_panda_urdf()))


def test_workers_starting_together_on_a_fresh_machine_build_the_cache_once(tmp_path, monkeypatch):
    """An episode loop's two workers start at once with no cache: one builds it, the other waits for it, and both
    get a whole one that owns its collision meshes (no link into the ManiSkill that built it)."""
    monkeypatch.setenv("POLICY_COMPOSER_CACHE", str(tmp_path))
    built = tmp_path / "built.txt"

    def slow_copy(src, dst, ratio):  # a decimation slow enough that the second worker arrives during the first's
        with open(built, "a") as f:
            f.write(f"{src.name}\n")
        time.sleep(0.1)
        shutil.copy(src, dst)

    monkeypatch.setattr(panda_light, "_decimate_glb", slow_copy)
    fork = multiprocessing.get_context("fork")
    start, log = fork.Event(), fork.Queue()
    workers = [fork.Process(target=_build_in_a_worker, args=(start, log)) for _ in range(2)]
    for w in workers:
        w.start()
    start.set()
    for w in workers:
        w.join(120)
    assert [w.exitcode for w in workers] == [0, 0]
    urdfs = {log.get(timeout=5) for _ in workers}
    stock = sorted(p.name for p in (panda_light._PANDA_DIR / "franka_description" / "meshes" / "visual").glob("*.glb"))
    assert sorted(built.read_text().split()) == stock  # each mesh decimated once, by one worker
    (urdf,) = urdfs
    collision = Path(urdf).parent / "franka_description" / "meshes" / "collision"
    assert not collision.is_symlink() and any(collision.iterdir())
    assert not list(tmp_path.glob("*.building"))
