"""The physics section of an experiment file (pydantic): the world the fake robots live
in and the imperfections of MuJoCo robots. Units: kg, m, s, N m.
"""

from typing import Literal, Optional

from pydantic import Field

from curve_formation.core.config.strict import Strict


WHEEL_MASS = 0.005   # kg, each of a MuJoCo robot's two wheels (physics.mass includes them)


class ImperfectionsSpec(Strict):
    """What a real robot does that the paper's unicycle does not (physics: mujoco only).

    Each robot draws its own mismatch and gains from `seed`; all off by default.
    """

    wheel_radius_mismatch: float = Field(0.0, ge=0, lt=0.5, description='largest relative '
                                         "difference between a robot's two wheel radii; each "
                                         'robot draws its own in [-x, x]')
    motor_gain_spread: float = Field(0.0, ge=0, lt=0.5, description="each motor's gain "
                                     '(wheel speed per command) drawn in [1 - x, 1 + x]')
    dead_band: float = Field(0.0, ge=0, lt=1, description='wheel commands below this fraction '
                             'of limits.max_wheel_speed leave the motor off')
    command_bits: Optional[int] = Field(None, ge=2, le=32, description='wheel commands '
                                        'quantised to signed integers of this many bits over '
                                        "+-limits.max_wheel_speed (the firmware's resolution)")
    battery_sag: float = Field(0.0, ge=0, lt=1, description="fraction of every motor's gain "
                               'lost per 10 minutes (linear, from the start)')
    seed: int = Field(0, description='draws of the per-robot mismatch and gains')


class PhysicsSpec(Strict):
    """The world the fake robots live in: the paper's unicycle (kinematic, exact and fast) or
    MuJoCo bodies with wheels, motors, casters and friction. Defaults are a Mona robot's
    (docs/physics.md says where each number comes from and which are assumptions).
    """

    engine: Literal['kinematic', 'mujoco'] = Field(
        'kinematic', description='kinematic: unicycles (and discs pushed apart); mujoco: '
        'rigid bodies on driven wheels in the MuJoCo engine')
    timestep: float = Field(0.002, gt=0, le=0.01, description='MuJoCo integration step (s)')
    mass: float = Field(0.1, gt=2 * WHEEL_MASS, description='robot mass with its two '
                        f'wheels of {WHEEL_MASS * 1000:g} g (kg)')
    height: float = Field(0.03, gt=0, description='body height (m), for its inertia')
    caster_drag: float = Field(0.02, ge=0, description="the ball casters' drag against the "
                               "robot's motion at the wheels' top speed, as a fraction of its "
                               'weight (viscous)')
    floor_friction: float = Field(0.8, gt=0, description='wheel-floor friction coefficient: '
                                  'lower, wheels slip sooner when robots push')
    motor_time_constant: float = Field(0.05, gt=0, description='first-order time constant '
                                       'of a wheel following its speed command (s)')
    motor_torque: float = Field(0.03, gt=0, description='torque limit of a wheel motor (N m)')
    motor_inertia: float = Field(3e-5, gt=0, description="the motor rotor's inertia seen at "
                                 'the wheel through its gearbox (kg m^2)')
    imperfections: ImperfectionsSpec = ImperfectionsSpec()
