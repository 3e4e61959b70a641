r"""Car-like vehicle with an encoder offset (Guivant & Nebot 2001, Sec. II).

The Victoria Park utility car is an Ackermann vehicle with wheelbase :math:`L`. Its
speed is read by an encoder on the rear-left wheel, :math:`H` to the left of the
rear-axle centre, so the speed of the rear-axle centre is

.. math::
    v_c = \frac{v_e}{1 - \tan(\alpha)\, H / L}, \qquad
    \omega = \frac{v_c \tan\alpha}{L},

with :math:`v_e` the encoder speed and :math:`\alpha` the steering angle. The pose
:math:`(x, y, \phi)` is that of a point fixed to the car at :math:`(A, B)` in the
rear-axle frame (forward, left) with the car's heading; for Victoria Park it is the
laser, :math:`A = L + a = 3.78` m, :math:`B = b = 0.5` m (ACFR ``info.txt``:
:math:`L = 2.83, H = 0.76, a = 0.95, b = 0.5`; UFastSLAM ``setconfigfile.m`` uses
``a = 3.78``). Its velocity gives the Euler step over a control held for :math:`\Delta t`:

.. math::
    x' &= x + \Delta t\,(v_c \cos\phi - \omega (A \sin\phi + B \cos\phi)) \\
    y' &= y + \Delta t\,(v_c \sin\phi + \omega (A \cos\phi - B \sin\phi)) \\
    \phi' &= \phi + \Delta t\, \omega .

:math:`A = B = 0` gives the rear-axle-centre (bicycle) model. A control row with
:math:`\Delta t \le 0` (the padding rows of a sequence) leaves the pose bit-for-bit
unchanged. The functions are written for one pose; ``vmap`` them for batches.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxslam.core.se2 import wrap_angle


class CarGeometry(NamedTuple):
    """Car geometry [m] (traced values). Defaults: Victoria Park, pose = laser.

    Attributes:
        wheelbase: ``L``, rear axle to front axle.
        encoder_offset: ``H``, lateral offset of the speed encoder (left positive).
        point_forward: ``A``, forward offset of the tracked point from the rear axle.
        point_left: ``B``, left offset of the tracked point from the centre line.
    """

    wheelbase: Array | float = 2.83
    encoder_offset: Array | float = 0.76
    point_forward: Array | float = 2.83 + 0.95
    point_left: Array | float = 0.5


def centre_speed(encoder_speed: Array, steering: Array, geometry: CarGeometry) -> Array:
    """Speed of the rear-axle centre from the rear-left encoder speed."""
    return _centre_speed(encoder_speed, jnp.tan(steering), geometry)


def _centre_speed(encoder_speed: Array, tan_steering: Array, geometry: CarGeometry) -> Array:
    return encoder_speed / (1.0 - tan_steering * geometry.encoder_offset / geometry.wheelbase)


def motion_step(
    pose: Array, cos_heading: Array, sin_heading: Array, encoder_speed: Array, tan_steering: Array, dt: Array,
    geometry: CarGeometry,
) -> Array:
    """The Euler step of the car model (module docstring) from precomputed
    trigonometry: ``cos_heading``, ``sin_heading`` of ``pose[..., 2]`` and
    ``tan_steering``; the heading is not wrapped and ``dt <= 0`` is not special.

    :func:`car_motion` is this step for one pose. Broadcasts over leading axes, so a
    caller that evaluates the model at many points sharing few headings or steering
    angles (the unscented prediction's 11 sigma points have 7 headings and 3 steering
    angles) computes the trigonometry once per distinct value.

    Returns:
        ``(..., 3)`` moved poses.
    """
    v_c = _centre_speed(encoder_speed, tan_steering, geometry)
    omega = v_c * tan_steering / geometry.wheelbase
    c, s = cos_heading, sin_heading
    a, b = geometry.point_forward, geometry.point_left
    return jnp.stack(
        [
            pose[..., 0] + dt * (v_c * c - omega * (a * s + b * c)),
            pose[..., 1] + dt * (v_c * s + omega * (a * c - b * s)),
            pose[..., 2] + dt * omega,
        ],
        -1,
    )


def car_motion(pose: Array, control: Array, geometry: CarGeometry = CarGeometry()) -> Array:
    """One Euler step of the car model.

    Args:
        pose: ``(3,)`` ``[x, y, phi]`` of the tracked point.
        control: ``(3,)`` ``[encoder speed m/s, steering rad, dt s]``.
        geometry: car geometry.

    Returns:
        The new pose ``(3,)``, heading wrapped; ``pose`` itself when ``dt <= 0``.
    """
    speed, steering, dt = control[0], control[1], control[2]
    moved = motion_step(pose, jnp.cos(pose[2]), jnp.sin(pose[2]), speed, jnp.tan(steering), dt, geometry)
    moved = jnp.stack([moved[0], moved[1], wrap_angle(moved[2])])
    return jnp.where(dt > 0, moved, pose)


def car_motion_noisy(pose: Array, noise: Array, control: Array, geometry: CarGeometry = CarGeometry()) -> Array:
    """:func:`car_motion` with additive control noise ``[speed, steering]`` (the
    process model of an unscented prediction over ``[pose; noise]``)."""
    noisy = jnp.stack([control[0] + noise[0], control[1] + noise[1], control[2]])
    return car_motion(pose, noisy, geometry)
