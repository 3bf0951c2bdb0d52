"""The decimated Panda: built once into the cache, far fewer triangles, same materials."""


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
