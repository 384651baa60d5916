"""Slide: the smallest TMOC domain, to read in one sitting (docs/DOMAINS.md in tmoc-service).

A row of pucks of unknown friction; the robot pushes each one and lets go, and the puck
slides on to rest. Where it stops depends on its friction, which is L: Y lets go earlier
for a slippery puck. The task: every puck on the goal line, none pushed past it.
"""

DOMAIN = {
    "physics": "tmoc_slide_domain.physics:SlidePhysics",
    "task": "tmoc_slide_domain.task:SlideTask",
    "description": "pucks of unknown friction pushed and let go to slide onto a line (the smallest example)",
    "version": 1,
}
