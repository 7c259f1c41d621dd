"""The CR3 testbed in pybullet: robot, scenes, camera, oracle and pick episodes.

Entry points: ``env.SimEnv`` (one pybullet client; ``reset(SceneSpec)``), ``scene.capture``,
``oracle.gt_rois`` / ``oracle.oracle_grasp`` and ``episode.execute_pick``. Assets are read from
the shared folder (``CRAFT_SHARED``) and never modified.
"""
