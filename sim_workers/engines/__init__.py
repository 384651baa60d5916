"""Engine backends: each builds a ``sim_workers.scene.SceneDescription`` in its engine.

pybullet (``pybullet_engine``) is the one engine today and the default; a second engine is
a module beside it over the same descriptions, so no domain keeps a hand-written copy of
its scene per engine.
"""
