"""The MuJoCo world: a ``GroundedWorld`` over one compiled model (``mujoco_engine``).

MuJoCo keeps every piece of simulation state in ``MjData`` (warm starts included) and
``mj_resetData`` clears all of it, so a reset is a fresh data on the model of the
hypothesis: bit-identical to a fresh process without rebuilding anything (checked in
tests/sim_workers/test_determinism.py). A new hypothesis that changes only blocks' boxes
and masses is written into the world's model in place (``mujoco_engine.patch``: the model
compiling it would give, bit for bit); anything else compiles its scene. The few model
fields a trajectory changes (the drives' force limits) are set by every reset's first
command.

A world steps in blocks, not one Python call per physics step (issue 27): an action's
steps are cut only where the loop must look at the state or change the model (a force
limit changes, a guarded move ends, a rest check is due: ``blocks``); a block whose drive
targets move is one ``mujoco.rollout`` call (targets as its open-loop controls, the
world's own data and warm start, so nothing outside the state vector is lost), a block
that holds its targets one ``mj_step(nstep)``. The result is bit for bit the one-step
loop's (``GroundedWorld._run``; tests/sim_workers/test_engines.py). Why a shard's
particles are not stepped in one rollout call across worlds: ``rollout`` runs a batch on
one ``MjData`` per thread, restoring only the state vector per model; the sleeping
islands and the solver's warm start live outside it, so a particle's physics would depend
on which particle ran before it on that data.
"""
from __future__ import annotations

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from ..configuration import Configuration
from ..domains import Domain
from ..grounded_world import REST_ANGULAR, REST_CHECK_EVERY, REST_LINEAR, GroundedWorld, Outcome
from .mujoco_engine import MujocoScene, build_model, patch

CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
MOCAP_POS = int(mujoco.mjtState.mjSTATE_MOCAP_POS)
MOCAP_QUAT = int(mujoco.mjtState.mjSTATE_MOCAP_QUAT)
FULLPHYSICS = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)


def blocks(times: np.ndarray, targets: np.ndarray, t_end: float) -> list[tuple[int, int, bool]]:
    """The action's steps as (start, stop, rest check after the last) blocks: cut where
    the efforts (grip force, force limit) change, a guarded move's release being one
    such change, and after every step at which ``GroundedWorld._run`` checks for rest
    (past the trajectory's end, every ``REST_CHECK_EVERY``-th step)."""
    n = len(times)
    cuts = {0, n}
    if targets.shape[1] > 6:
        cuts.update((np.flatnonzero(np.any(targets[1:, 5:7] != targets[:-1, 5:7], axis=1)) + 1).tolist())
    late = np.flatnonzero(times > t_end)
    checks = set()
    if len(late):
        first = -(-int(late[0]) // REST_CHECK_EVERY) * REST_CHECK_EVERY
        checks = {k + 1 for k in range(first, n, REST_CHECK_EVERY)}
    cuts |= checks
    edges = sorted(cuts)
    return [(a, b, b in checks) for a, b in zip(edges[:-1], edges[1:])]


def wxyz(q) -> np.ndarray:
    """A quaternion (x, y, z, w), as configurations carry it, in MuJoCo's (w, x, y, z)."""
    return np.array([q[3], q[0], q[1], q[2]], dtype=np.float64)


def xyzw(q) -> np.ndarray:
    return np.array([q[1], q[2], q[3], q[0]], dtype=np.float64)


class MujocoWorld(GroundedWorld):
    """One MuJoCo model and data holding one scene of `domain` (leaves nothing out: the
    contacts of far bodies cost MuJoCo little; ``leave_out`` is accepted and ignored)."""

    engine = "mujoco"
    # mj_step and rollout release the GIL, and each world owns its model and data (measured:
    # two threads step two worlds x1.43-1.94 as fast as one: benchmarks/bench_threads.py).
    steps_in_threads = True

    def __init__(self, domain: Domain, *, leave_out: bool = False, engine: str | None = None) -> None:
        super().__init__(domain, leave_out=False)

    def _connect(self) -> None:
        self._desc = None                   # the scene description the model holds
        self.scene: MujocoScene | None = None
        self.model = self.data = None
        self._target = np.zeros(6)          # palm x, y, z, yaw, finger q, finger q
        self._sent: tuple | None = None
        self._tare = 0.0
        self._links: tuple = ()             # the arm's capsules the model holds (mocap bodies)
        self._rollout = mj_rollout.Rollout(nthread=0)   # on the calling thread

    def close(self) -> None:
        self.scene = self.model = self.data = self._desc = None

    @property
    def time_step(self) -> float:
        return self.scene.time_step

    def _rebuild(self, props: dict) -> None:
        desc = self.domain.scene_description(props)
        if desc != self._desc and not (self.scene is not None and self._desc is not None
                                       and patch(self.scene, self._desc, desc, self.data)):
            self.scene = build_model(desc, self._links)
            self.model, self.data = self.scene.model, mujoco.MjData(self.scene.model)
        self._desc = desc
        mujoco.mj_resetData(self.model, self.data)
        self._sent = None

    def _apply(self, config: Configuration) -> None:
        s, d = self.scene, self.data
        for i, pose in enumerate(config.objects):
            adr, dof = s.object_qpos[i], s.object_dof[i]
            if adr < 0:
                continue                   # a fixture: it stays where the scene put it
            d.qpos[adr:adr + 3] = pose[:3]
            d.qpos[adr + 3:adr + 7] = wxyz(pose[3:7])
            d.qvel[dof:dof + 6] = 0.0
        self._set_gripper(config.robot, reset=True)
        mujoco.mj_forward(self.model, d)

    def _set_gripper(self, target: np.ndarray, reset: bool = False) -> None:
        """See ``GroundedWorld._set_gripper``: capped velocity drives toward the target."""
        s, d, m = self.scene, self.data, self.model
        q = float(target[4]) / 2.0 + s.finger_inner
        grip = float(target[5]) if len(target) > 5 else s.grip_force
        limit = float(target[6]) if len(target) > 6 else self.domain.base_max_force
        self._target[:] = (target[0], target[1], float(target[2]) + s.palm_offset, target[3], q, q)
        d.ctrl[list(s.palm_actuators) + list(s.finger_actuators)] = self._target
        if reset:
            p, v = s.palm_qpos, s.palm_dof
            d.qpos[p:p + 4] = self._target[:4]
            d.qvel[v:v + 4] = 0.0
            for a, b in zip(s.finger_qpos, s.finger_dof):
                d.qpos[a] = q
                d.qvel[b] = 0.0
        if (limit, grip) != self._sent:
            for a in s.palm_actuators:
                m.actuator_forcerange[a] = (-limit, limit)
            for a in s.finger_actuators:
                m.actuator_forcerange[a] = (-grip, grip)
            self._sent = (limit, grip)
            # The sensor adds the weight the arm carries outside a guarded move (see
            # mujoco_engine: the gripper is gravity-compensated throughout).
            guarded = limit < self.domain.base_max_force
            self._tare = 0.0 if guarded else s.gripper_mass * -float(m.opt.gravity[2])

    def _with_links(self, links: tuple) -> None:
        """See ``GroundedWorld._with_links``: mocap capsules paired with the movable bodies;
        a model without them is compiled with them (once per world: later hypotheses patch
        it), the scene put back as it stood."""
        links = tuple(links)
        if links == self._links:
            return
        config = self._placed if self._fresh else self.observe()
        self._links, self._desc = links, None
        self.reset(config, self.props, place=False)

    def _place_links(self, positions: np.ndarray, quaternions: np.ndarray) -> None:
        ids = list(self.scene.links)
        self.data.mocap_pos[ids] = positions
        self.data.mocap_quat[ids] = np.asarray(quaternions)[:, [3, 0, 1, 2]]

    def _step(self) -> None:
        mujoco.mj_step(self.model, self.data)

    def _run(self, action: str, times: np.ndarray, targets: np.ndarray, t_end: float,
             watch) -> tuple[Outcome | None, int]:
        """``GroundedWorld._run`` in blocks (see the module's doc); `watch` is always None
        here (nothing is left out)."""
        logging = bool(self.domain.logs_sensors) and bool(self.domain.senses(action))
        base = self.domain.base_max_force
        guarded = targets.shape[1] > 6 and bool(np.any(targets[:, 6] < base))
        offset = np.zeros(3)
        force, opening = [], []
        steps = 0
        for a, b, check in blocks(times, targets, t_end):
            if guarded and a > 0 and targets[a - 1, 6] < base <= targets[a, 6]:
                offset = self._tool_position() - self._commanded_tool()
            rows = targets[a:b]
            if np.any(offset):
                rows = rows.copy()
                rows[:, :3] += offset
            self._set_gripper(rows[0])
            links = None if self._links_track is None else (self._links_track[0][a:b], self._links_track[1][a:b])
            logged = self._advance(rows, logging, links)
            if logging:
                force.append(logged[0])
                opening.append(logged[1])
            steps = b
            if check and self.at_rest():
                break
        if logging:
            logged = (np.concatenate(force), np.concatenate(opening))
        return self._finish(action, times, targets, t_end, steps, logged if logging else None), steps

    def _controls(self, rows: np.ndarray) -> np.ndarray:
        """The drives' targets (``_set_gripper``'s, one row per step) as rollout controls."""
        s = self.scene
        ctrl = np.empty((len(rows), self.model.nu))
        q = rows[:, 4] / 2.0 + s.finger_inner
        ctrl[:, list(s.palm_actuators)] = rows[:, :4]
        ctrl[:, s.palm_actuators[2]] = rows[:, 2] + s.palm_offset
        ctrl[:, s.finger_actuators[0]] = q
        ctrl[:, s.finger_actuators[1]] = q
        return ctrl

    def _advance(self, rows: np.ndarray, logging: bool, links: tuple | None = None):
        """Step once per row of drive targets (efforts constant: ``_set_gripper`` has set
        them and the first row) and, with `links` (centres (n, L, 3), quaternions (n, L, 4)),
        of an arm's link poses; with `logging`, the wrist forces (n, 3) and openings (n,)."""
        m, d, s = self.model, self.data, self.scene
        n = len(rows)
        still = n == 1 or not np.any(rows[1:, :5] != rows[0, :5])
        spec = CTRL
        if links is not None:
            self._place_links(links[0][0], links[1][0])
            still = still and not (np.any(links[0][1:] != links[0][0]) or np.any(links[1][1:] != links[1][0]))
        if still and not logging:
            mujoco.mj_step(m, d, n)
            return None
        ctrl = self._controls(rows)
        if links is not None:
            # the links' poses ride along as controls (rollout sets them before each step)
            spec = CTRL | MOCAP_POS | MOCAP_QUAT
            mocap = np.empty((n, m.nmocap, 7))
            mocap[:, :, :3], mocap[:, :, 3:] = d.mocap_pos, d.mocap_quat
            ids = list(s.links)
            mocap[:, ids, :3] = links[0]
            mocap[:, ids, 3:] = links[1][:, :, [3, 0, 1, 2]]
            ctrl = np.concatenate([ctrl, mocap[:, :, :3].reshape(n, -1), mocap[:, :, 3:].reshape(n, -1)], axis=1)
        state0 = np.empty(mujoco.mj_stateSize(m, FULLPHYSICS))
        mujoco.mj_getState(m, d, state0, FULLPHYSICS)
        states = np.empty((1, n, len(state0))) if logging else None
        sensed = np.empty((1, n, m.nsensordata)) if logging else None
        t0 = d.time
        self._rollout.rollout([m], [d], state0[None], ctrl[None], control_spec=spec, skip_checks=True,
                              nstep=n, initial_warmstart=d.qacc_warmstart.copy()[None],
                              state=states, sensordata=sensed)
        done = n
        if any(d.warning.number):
            # rollout stops a batch at a warning (an unstable step); the one-step loop
            # goes on, so the rest is stepped here as it would have been.
            done = int(round((d.time - t0) / m.opt.timestep))
            for k in range(done, n):
                mujoco.mj_setState(m, d, ctrl[k], spec)
                mujoco.mj_step(m, d)
                if logging:
                    mujoco.mj_getState(m, d, states[0, k], FULLPHYSICS)
                    sensed[0, k] = d.sensordata
        self._target[:] = ctrl[-1, list(s.palm_actuators) + list(s.finger_actuators)]
        if links is not None:
            self._place_links(links[0][-1], links[1][-1])
        if not logging:
            return None
        force = sensed[0, :, :3].copy()
        force[:, 2] += self._tare
        q = states[0][:, 1 + np.array(s.finger_qpos)]
        return force, 2.0 * (np.mean(q, axis=1) - s.finger_inner)

    def observe(self) -> Configuration:
        s, d = self.scene, self.data
        p = s.palm_qpos
        x, y, z, yaw = (float(v) for v in d.qpos[p:p + 4])
        yaw = float(np.arctan2(np.sin(yaw), np.cos(yaw)))
        opening = 2.0 * (float(np.mean(d.qpos[list(s.finger_qpos)])) - s.finger_inner)
        robot = np.array([x, y, z - s.palm_offset, yaw, opening])
        objects = np.empty((len(s.objects), 7))
        for i, body in enumerate(s.objects):
            adr = s.object_qpos[i]
            if adr < 0:
                objects[i, :3] = d.xpos[body]
                objects[i, 3:] = xyzw(d.xquat[body])
            else:
                objects[i, :3] = d.qpos[adr:adr + 3]
                objects[i, 3:] = xyzw(d.qpos[adr + 3:adr + 7])
        return Configuration(robot, objects)

    def at_rest(self) -> bool:
        s, d = self.scene, self.data
        for dof in s.object_dof:
            if dof < 0:
                continue
            v = d.qvel[dof:dof + 6]
            if np.max(np.abs(v[:3])) > REST_LINEAR or np.max(np.abs(v[3:])) > REST_ANGULAR:
                return False
        return True

    def _wrist_force(self):
        f = self.data.actuator_force
        a = self.scene.palm_actuators
        return (float(f[a[0]]), float(f[a[1]]), float(f[a[2]]) + self._tare)

    def _opening(self) -> float:
        s = self.scene
        return 2.0 * (float(np.mean(self.data.qpos[list(s.finger_qpos)])) - s.finger_inner)

    def _tool_position(self) -> np.ndarray:
        s = self.scene
        pos = self.data.qpos[s.palm_qpos:s.palm_qpos + 3].copy()
        pos[2] -= s.palm_offset
        return pos

    def _commanded_tool(self) -> np.ndarray:
        out = self._target[:3].copy()
        out[2] -= self.scene.palm_offset
        return out
