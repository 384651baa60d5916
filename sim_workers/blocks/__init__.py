"""The block-world toolkit: the public pieces the built-in block domains (container,
stack_and_push) are built from, so that they are siblings and neither imports the other.

- ``scene``: physics settings, table, cubes and the floating gripper (pybullet);
- ``hand``: which block is held, and the grasp's yaw of a cube;
- ``terms``: the action terms pickup/stack/push as the physics half parses them.

Generic pieces of any domain stay beside it (``sim_workers.base``, ``configuration``,
``obstacles``, ``properties``, ``trajectory``).
"""
