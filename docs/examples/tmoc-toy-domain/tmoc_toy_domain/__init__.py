"""An example TMOC domain plugin (see docs/DOMAINS.md in tmoc-service).

The registry imports nothing from here until the domain is used, and then only the half
it needs: Ray shard actors import the physics half, the coordinator the task half.
"""

DOMAIN = {
    "physics": "tmoc_toy_domain.physics:ToyTrayPhysics",
    "task": "tmoc_toy_domain.task:ToyTrayTask",
    "description": "example plugin: four blocks, a short tray run and cheaper actions",
    "version": 1,            # optional, default 1
}
