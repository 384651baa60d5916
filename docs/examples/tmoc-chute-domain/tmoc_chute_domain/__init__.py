"""The chute: a TMOC domain that is not a block world (docs/DOMAINS.md in tmoc-service).

Pucks of unknown friction, loaded from a mesh this package ships, queued in a lane and
swept in trains to a goal line by a force-limited wrist. The registry imports nothing from
here until the domain is used, and then only the half it needs: Ray shard actors import
the physics half, the coordinator the task half.
"""

DOMAIN = {
    "physics": "tmoc_chute_domain.physics:ChutePhysics",
    "task": "tmoc_chute_domain.task:ChuteTask",
    "description": "pucks of unknown friction swept along a lane in trains (not a block world)",
    "version": 1,
}
