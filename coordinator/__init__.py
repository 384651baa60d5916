"""coordinator package of the TMOC service: the TMOC loop and what runs it, by concept.

``loop/`` (the session, episodes, the runner, the reality), ``particle_filter/`` (the
belief over L), ``transition/`` (T and the experience pool), ``distributed/`` (Ray),
``integrations/`` (Gymnasium, TensorBoard, MCAP, pictures), ``baselines/``,
``experiments/`` and ``commands/``; the registries' view (``domains``, ``engines``),
``run_config``, ``agents``, ``conformance`` and ``cli`` at the top.

The modules that moved into those folders (issue 39) keep their old names as aliases:
``import coordinator.session`` is ``coordinator.loop.session`` itself, so pickles,
checkpoints, ``gymnasium.make("coordinator.gym_env:...")`` ids and scripts that name a
module keep working (``python -m coordinator.reaper`` included).
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

# old name -> the folder it moved to
MOVED = {"session": "loop", "episode": "loop", "runner": "loop", "real_pose": "loop", "transit": "loop",
         "reality": "loop", "step_record": "loop", "observations": "loop",
         "transition_model": "transition", "experience": "transition",
         "fanout": "distributed", "shard_pools": "distributed", "reaper": "distributed",
         "gym_env": "integrations", "tracker": "integrations", "export": "integrations", "frames": "integrations",
         "grounding_bandit": "baselines", "gym_baselines": "baselines"}


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``coordinator.<old name>`` and hands back the moved module itself."""

    def find_spec(self, fullname, path=None, target=None):
        package, _, name = fullname.rpartition(".")
        if package != __name__ or name not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def _target(self, fullname: str) -> str:
        name = fullname.rpartition(".")[2]
        return f"{__name__}.{MOVED[name]}.{name}"

    def create_module(self, spec):
        return importlib.import_module(self._target(spec.name))

    def exec_module(self, module) -> None:
        """Nothing to run: the module ran under its new name."""

    def get_code(self, fullname):          # `python -m coordinator.<old name>`
        target = self._target(fullname)
        return importlib.util.find_spec(target).loader.get_code(target)


if not any(isinstance(f, _Alias) for f in sys.meta_path):
    sys.meta_path.append(_Alias())
