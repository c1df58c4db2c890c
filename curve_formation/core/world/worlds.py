"""The world the fake robots live in, as the experiment's physics.engine says: the paper's
unicycles (kinematic_world) or MuJoCo bodies on driven wheels (mujoco_world). Both take
velocity commands and give poses and contacts through the same methods.
"""

from typing import TYPE_CHECKING, Union

from curve_formation.core.world.kinematic import KinematicWorld, PHYSICS_DT


if TYPE_CHECKING:
    from curve_formation.core.config.experiment import Experiment
    from curve_formation.core.world.mujoco_world import MujocoWorld


ENGINES = ('kinematic', 'mujoco')
World = Union[KinematicWorld, 'MujocoWorld']


def make_world(experiment: 'Experiment', engine: str | None = None, latency: float = 0.0,
               timeout: float = 0.0, physics_dt: float = PHYSICS_DT, jitter: float = 0.0,
               seed: int = 0) -> World:
    """The experiment's world: `engine` ('kinematic' or 'mujoco'; None: physics.engine), each
    command acting `latency` s (+- a uniform `jitter` s, drawn from `seed`) after it came,
    motors off `timeout` s (0: never) after the last; physics_dt (s): the kinematic world's
    longest step between contact resolutions.
    """
    engine = experiment.spec.physics.engine if engine is None else engine
    if engine == 'mujoco':
        try:
            from curve_formation.core.world.mujoco_world import MujocoWorld
        except ImportError as exc:
            raise ValueError(f'physics engine mujoco needs the mujoco package ({exc}): '
                             'pip install mujoco') from None
        return MujocoWorld(experiment, latency, timeout, jitter, seed)
    if engine not in ENGINES:
        raise ValueError(f'physics engine {engine!r}: expected one of {", ".join(ENGINES)}')
    return KinematicWorld(experiment, latency, timeout, physics_dt, jitter, seed)
