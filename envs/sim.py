"""The one owner of a PyBullet world.

Every environment creates one :class:`Simulation`; robots, scenes and cameras receive it
and never touch the global ``pybullet`` connection, so any number of worlds live side by
side in one process. ``close()`` disconnects the client (an open DIRECT client costs
about 28 MB); after it, every use of the world raises :class:`EnvClosedError`.
"""

from __future__ import annotations

from importlib import resources
from typing import cast

from gymnasium.error import ClosedEnvironmentError

from observer_gym.envs.bullet import BulletClient, pybullet, pybullet_data, silenced

GRAVITY_MPS2 = 9.81


def asset_path(name: str) -> str:
    """Absolute path of a file shipped in ``observer_gym/envs/assets``."""
    path = resources.files("observer_gym.envs") / "assets" / name
    if not path.is_file():
        raise FileNotFoundError(f"asset {name!r} is not in the package's assets folder")
    return str(path)


class EnvClosedError(ClosedEnvironmentError, RuntimeError):
    """An env (or its world) used after ``close()`` and before the next ``reset()``."""


CLOSED_MESSAGE = (
    "this env was closed (close() disconnected its PyBullet world); "
    "call reset() to build a new world"
)


class _ClosedClient:
    """The client of a closed Simulation: every PyBullet call raises EnvClosedError
    (instead of PyBullet's "Not connected to physics server")."""

    _client = -1

    def __getattr__(self, name: str):
        raise EnvClosedError(f"{name}(): {CLOSED_MESSAGE}")


class Simulation:
    """A PyBullet world in DIRECT mode with a fixed physics time step.

    Args:
        physics_dt_s: the physics time step in seconds.
    """

    def __init__(self, physics_dt_s: float) -> None:
        if not physics_dt_s > 0:
            raise ValueError(f"physics_dt_s must be > 0, got {physics_dt_s}")
        self.physics_dt_s = float(physics_dt_s)
        # Counts the changes of the world: every step and clear here, and every step or
        # teleport a scene makes through the client (it calls touch()). A query of the
        # world made at one version holds until the version changes (envs cache their
        # per-tick ground truth on it).
        self.version = 0
        with silenced(1):  # PyBullet prints "argv[0]=" on every connection
            self.client = BulletClient(connection_mode=pybullet.DIRECT)
        self.client.setAdditionalSearchPath(pybullet_data.getDataPath())
        self._configure()

    def _configure(self) -> None:
        self.client.setGravity(0.0, 0.0, -GRAVITY_MPS2)
        self.client.setTimeStep(self.physics_dt_s)
        self.client.setPhysicsEngineParameter(deterministicOverlappingPairs=1)

    def clear(self) -> None:
        """Remove every body and start afresh (keeps the connection and settings).

        The reliable way to make an episode independent of the previous ones:
        ``restoreState`` restores poses and velocities but neither constraint warm-start
        impulses nor the renderer's caches, so a restored world can render and step a
        little differently from a new one.
        """
        self.client.resetSimulation()
        self._configure()
        self.version += 1

    def touch(self) -> None:
        """Record a change of the world made through the client (a step or a teleport)."""
        self.version += 1

    @property
    def client_id(self) -> int:
        """PyBullet's id of the client; -1 after :meth:`close`."""
        return self.client._client

    @property
    def is_closed(self) -> bool:
        """Whether :meth:`close` disconnected the client (no PyBullet call)."""
        return self.client._client < 0

    def check_open(self, call: str) -> None:
        """EnvClosedError naming ``call`` if the world is closed."""
        if self.client._client < 0:
            raise EnvClosedError(f"{call}: {CLOSED_MESSAGE}")

    @property
    def is_connected(self) -> bool:
        return self.client._client >= 0 and bool(
            pybullet.getConnectionInfo(physicsClientId=self.client._client)["isConnected"]
        )

    def step(self, substeps: int = 1) -> None:
        step, client_id = pybullet.stepSimulation, self.client._client
        self.version += 1
        for _ in range(substeps):
            step(physicsClientId=client_id)

    def close(self) -> None:
        """Disconnect the client. Safe to call more than once. From then on every call
        through :attr:`client` raises :class:`EnvClosedError`, and ``version`` has moved
        on, so that nothing cached from the world is taken as current."""
        if self.client._client >= 0:
            self.client.disconnect()
            self.client._client = -1
            # a stand-in with the client's calls, each raising EnvClosedError
            self.client = cast(BulletClient, _ClosedClient())
            self.version += 1
