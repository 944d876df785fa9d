from pcmgn_jax.scene import PAPER_SCENE_FILE, Scene, default_scene


def test_shipped_scene_file_is_the_default_scene():
    assert Scene.load(PAPER_SCENE_FILE) == default_scene()
