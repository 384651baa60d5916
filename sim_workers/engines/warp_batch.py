"""MuJoCo Warp: a shard's particle worlds stepped as one batch (issue 42, item 5).

The engine that comes after the CPU: MuJoCo Warp (``mujoco_warp``, an optional extra:
``pip install 'tmoc-service[warp]'``) steps K worlds of one model in one call, on a GPU
or, slowly, on the CPU, and takes per-world model parameters natively, which is what a
particle is (its block sizes and masses).

How a batch runs. Every particle keeps a CPU twin (a ``MujocoWorld``): the twin is reset
to the particle's hypothesis (its compiled model gives the per-world parameters), runs
the grounded world's own one-step control loop (``GroundedWorld._run``: drive targets,
force limits, guarded moves, rest checks, the sensor log) on a thread of its own, and
reads the outcome (Y^-1, measurements) when done. Only the physics step is shared: each
twin's ``_step`` waits at a barrier until every twin still running has asked for a
step; then their controls and force limits go to the device, one ``mujoco_warp.step``
advances all K worlds, and each twin's state (qpos, qvel, actuator forces) comes back.
A twin that is done (its trajectory over, or at rest) leaves the barrier with the state
of its last step; its device world steps on unread.

What it is not: bit-identical. MuJoCo Warp computes in float32 and its worlds share
kernels, so a world's result moves at the 1e-9 level with the rest of its batch, and by
~1e-7 from CPU MuJoCo over an action (measured on the container's pickup); placements
exactly in contact (distance ~1e-17) may decide differently. It is judged like the
engines against each other: by the probe tables, outcome shares within their sampling
error (``tests/sim_workers/test_warp_engine.py``). The determinism guarantee across
shards and splits is the CPU engines'. Sleeping islands are off on the device (MuJoCo
Warp supports them, but on the CPU they made a step 3-5x slower: 866 kernel launches a
step against 110).

What limits it: the controller is the twins' Python, one thread per world, so a step
costs K x (the twin's Python, ~20-30 us) besides the device's batch step. On an H200 the
batch step alone runs a container pickup x16.6 as fast as one CPU core (32 768 worlds,
``benchmarks/bench_warp.py --raw``), while at 1 024 worlds the twins' Python (~25 ms a
step) outweighs the device's 8.7 ms: a controller vectorised over the worlds is the next
step. On a CPU device the batch step is 5-30x slower than K ``mj_step`` calls.
"""
from __future__ import annotations

import copy
import dataclasses
import threading

import mujoco
import numpy as np

from ..grounded_world import GroundedWorld
from .mujoco_world import MujocoWorld

# Per world: contacts and constraint rows the device reserves. The container's pickup
# needs up to 109 constraint rows (133 without sleeping); past the reservation MuJoCo
# Warp drops constraints (with a printed "overflow"), so these are generous.
NCONMAX = 128
NJMAX = 512
# Model fields a hypothesis changes that MuJoCo Warp holds once for every world, harmless
# here: a dof's length scales only the sleeping thresholds, and sleeping is off on the device.
SHARED_OK = frozenset({"dof_length"})


def device_name() -> str:
    """"cuda" where Warp sees a GPU, else "cpu".

    Warp's run-to-run deterministic mode for atomics is not set: it cannot compile MuJoCo
    Warp's constraint kernel (``nefc_out`` is both read and atomically updated; measured on
    an H200, WarpDeterminismError). On a GPU the order of atomic additions may then vary
    from run to run (at float32 rounding); a CPU device is deterministic."""
    import warp as wp

    wp.config.log_level = max(int(wp.config.log_level), 30)     # no line per module load
    wp.init()
    return "cuda" if wp.get_cuda_device_count() > 0 else "cpu"


class _Twin(MujocoWorld):
    """A particle's CPU twin: the grounded world's one-step loop, its steps taken by the batch."""

    engine = "mujoco_warp"
    steps_in_threads = False
    _run = GroundedWorld._run          # one physics step per call: the batch steps in lockstep

    def __new__(cls, *args, **kwargs):
        return object.__new__(cls)

    def __init__(self, domain, batch: "WarpBatch", index: int) -> None:
        super().__init__(domain)
        self._batch, self._index = batch, index

    def _step(self) -> None:
        self._batch._request_step(self._index)


class WarpBatch:
    """K particle worlds of one domain, stepped together by MuJoCo Warp on `device`."""

    def __init__(self, domain, device: str | None = None) -> None:
        import warp as wp

        self.domain = domain
        self.device = device or device_name()
        self._wp = wp
        self._cv = threading.Condition()
        self.twins: list[_Twin] = []
        self.kernel_steps = 0                 # batch steps taken (each advances every world)

    # -- one action for a batch of particles ----------------------------------------------
    def run(self, config, props: list[dict], action: str, trajectories: list[np.ndarray],
            starts: np.ndarray) -> list:
        """The outcome of `action` in every particle's world (row order), each twin reset to
        its `props`, its trajectory from its start time."""
        while len(self.twins) < len(props):
            self.twins.append(_Twin(self.domain, self, len(self.twins)))
        twins = self.twins[:len(props)]
        for twin, p in zip(twins, props):
            twin.reset(config, p)
        outs: list = [None] * len(twins)
        # Worlds of one structure share a batch (a hypothesis that changes the scene's
        # structure, not only sizes and masses, compiles another model).
        groups: dict[tuple, list[int]] = {}
        for i, t in enumerate(twins):
            m = t.model
            groups.setdefault((m.nq, m.nv, m.nu, m.nbody, m.ngeom, m.npair, m.neq), []).append(i)
        for rows in groups.values():
            self._run_group([twins[i] for i in rows], rows, action, trajectories, starts, outs)
        return outs

    def _run_group(self, twins, rows, action, trajectories, starts, outs) -> None:
        self._begin(twins)
        errors: list[BaseException] = []

        def go(k: int, twin: _Twin, row: int) -> None:
            try:
                outs[row] = twin.execute(trajectories[row], action, start_time=float(starts[row]))
            except BaseException as exc:         # re-raised below, after every thread ends
                errors.append(exc)
            finally:
                self._leave(k)

        threads = [threading.Thread(target=go, args=(k, t, r), name=f"tmoc-warp-{k}", daemon=True)
                   for k, (t, r) in enumerate(zip(twins, rows))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        if errors:
            raise errors[0]

    # -- the lockstep -----------------------------------------------------------------------
    def _begin(self, twins: list[_Twin]) -> None:
        """The device batch of these twins (their models' per-world fields); the first step
        request loads their states."""
        self._group = twins
        for k, t in enumerate(twins):
            t._index = k
        self._alive = set(range(len(twins)))
        self._waiting: set[int] = set()
        self._generation = 0
        self._loaded = False
        self._failed: BaseException | None = None

    def _leave(self, k: int) -> None:
        with self._cv:
            self._alive.discard(k)
            self._maybe_step()

    def _request_step(self, k: int) -> None:
        with self._cv:
            self._waiting.add(k)
            gen = self._generation
            self._maybe_step()
            while self._generation == gen and self._failed is None:
                self._cv.wait()
            if self._failed is not None:
                raise RuntimeError("warp batch: the batch step failed") from self._failed

    def _maybe_step(self) -> None:
        """Called holding the condition: step once every live twin is waiting."""
        if not self._alive or self._waiting != self._alive:
            return
        try:
            self._device_step(sorted(self._waiting))
        except BaseException as exc:
            self._failed = exc
        self._waiting = set()
        self._generation += 1
        self._cv.notify_all()

    def _device_step(self, live: list[int]) -> None:
        wp = self._wp
        import mujoco_warp as mjw

        twins = self._group
        with wp.ScopedDevice(self.device):
            if not self._loaded:
                self._load(twins)
                self._loaded = True
            ctrl = np.stack([t.data.ctrl for t in twins])
            self._data.ctrl.assign(ctrl.astype(np.float32))
            frange = np.stack([t.model.actuator_forcerange for t in twins])
            if not np.array_equal(frange, self._frange):
                self._model.actuator_forcerange.assign(frange.reshape(self._frange_shape).astype(np.float32))
                self._frange = frange
            mjw.step(self._model, self._data)
            self.kernel_steps += 1
            qpos, qvel = self._data.qpos.numpy(), self._data.qvel.numpy()
            force = self._data.actuator_force.numpy()
        for k in live:
            d = twins[k].data
            d.qpos[:] = qpos[k]
            d.qvel[:] = qvel[k]
            d.actuator_force[:] = force[k]
            d.time += twins[k].model.opt.timestep

    def _load(self, twins: list[_Twin]) -> None:
        """Put the twins' models (fields that differ per world batched) and states on the device."""
        import mujoco_warp as mjw

        k = len(twins)
        m0 = twins[0].model
        # The device model's array fields that the host model has too: those a hypothesis
        # can change for the device.
        fields = {f.name: getattr(f.type, "shape", ()) for f in dataclasses.fields(mjw.Model)
                  if isinstance(getattr(m0, f.name, None), np.ndarray)}
        differ = [name for name in fields
                  if any(not np.array_equal(getattr(t.model, name), getattr(m0, name)) for t in twins[1:])]
        unbatched = [name for name in differ if fields[name][:1] != ("*",) and name not in SHARED_OK]
        if unbatched:
            raise ValueError(f"engine mujoco_warp: this domain's hypotheses differ in model fields "
                             f"MuJoCo Warp keeps one of for all worlds: {', '.join(unbatched)}")
        batched = sorted({name for name in differ if name not in SHARED_OK} | {"actuator_forcerange"})
        host = copy.deepcopy(m0)
        host.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
        model = mjw.put_model(host, batch_sizes={name: k for name in batched})
        # A Newton solve that stops at its iteration limit is not an error (CPU MuJoCo stops
        # there as silently); overflows of the reserved contacts and rows still print.
        model.opt.warn_overflow &= ~int(mjw.OverflowType.ITERATIONS | mjw.OverflowType.LS_ITERATIONS)
        for name in batched:
            arr = getattr(model, name)
            shape = arr.numpy().shape
            arr.assign(np.stack([getattr(t.model, name) for t in twins]).reshape(shape).astype(arr.numpy().dtype))
        data = mjw.put_data(host, twins[0].data, nworld=k, nconmax=NCONMAX, njmax=NJMAX)
        for name in ("qpos", "qvel", "qacc_warmstart", "ctrl"):
            getattr(data, name).assign(np.stack([getattr(t.data, name) for t in twins]).astype(np.float32))
        data.time.assign(np.array([t.data.time for t in twins], dtype=np.float32))
        self._model, self._data = model, data
        self._frange = np.stack([t.model.actuator_forcerange for t in twins])
        self._frange_shape = model.actuator_forcerange.numpy().shape

    def close(self) -> None:
        for t in self.twins:
            t.close()
        self.twins = []
