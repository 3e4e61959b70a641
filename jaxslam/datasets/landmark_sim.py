"""A point-landmark world with ground truth, in the Victoria Park sequence format.

Host-side NumPy. A car (the model of :mod:`jaxslam.models.vehicle`, same equations)
drives laps of a circle with a proportional steering controller through a world of
point landmarks scattered around its path (kept a minimum distance apart). Every
step (one "scan") holds ``rows_per_step`` control rows ``[speed, steering, dt]``;
the recorded controls are the true ones plus white noise of ``speed_std`` and
``steering_std`` per row, which is exactly the filter's process-noise model. At the
end of each step the sensor (at ``sensor_offset`` on the car) sees every landmark
within ``max_range`` and the field of view ``fov``, as ``[range, bearing]`` with white
noise of ``range_std`` and ``bearing_std``.

The returned :class:`LandmarkSequence` has the fields of
:class:`jaxslam.datasets.victoria_park.VictoriaParkSequence` (``gps_*`` are the true
positions, so GPS metrics give the true error) plus the ground truth.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxslam.datasets.geometry import wrap_angle
from jaxslam.datasets.victoria_park import VictoriaParkSequence


@dataclasses.dataclass(frozen=True)
class LandmarkSequence(VictoriaParkSequence):
    """Simulated sequence with ground truth: the fields of
    :class:`~jaxslam.datasets.victoria_park.VictoriaParkSequence` (``gps_*`` are the
    true positions), plus:

    Attributes:
        true_poses: (T, 3) true pose after each step.
        true_controls: (T, K, 3) noise-free controls.
        landmarks: (L, 2) true landmark positions.
        associations: (T, Z) index of the observed landmark, -1 for padding.
    """

    true_poses: np.ndarray = None
    true_controls: np.ndarray = None
    landmarks: np.ndarray = None
    associations: np.ndarray = None


def _move(pose, speed, steering, dt, geometry):
    wheelbase, encoder, fwd, left = geometry
    tan_s = np.tan(steering)
    v_c = speed / (1.0 - tan_s * encoder / wheelbase)
    omega = v_c * tan_s / wheelbase
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return np.array(
        [
            pose[0] + dt * (v_c * c - omega * (fwd * s + left * c)),
            pose[1] + dt * (v_c * s + omega * (fwd * c - left * s)),
            wrap_angle(pose[2] + dt * omega),
        ]
    )


def _scatter_landmarks(rng, num, radius, band, min_separation):
    points: list[np.ndarray] = []
    tries = 0
    while len(points) < num and tries < 100 * num:
        tries += 1
        r = radius + rng.uniform(-band, band)
        a = rng.uniform(0, 2 * np.pi)
        p = np.array([r * np.cos(a), r * np.sin(a) + radius])
        if all(np.hypot(*(p - q)) >= min_separation for q in points):
            points.append(p)
    return np.array(points).reshape(-1, 2)


def simulate(
    seed: int = 0,
    num_steps: int = 300,
    rows_per_step: int = 8,
    dt: float = 0.025,
    speed: float = 4.0,
    radius: float = 25.0,
    num_landmarks: int = 60,
    landmark_band: float = 15.0,
    min_separation: float = 4.0,
    speed_std: float = 0.5,
    steering_std: float = math.radians(2.0),
    range_std: float = 0.3,
    bearing_std: float = math.radians(1.0),
    max_range: float = 30.0,
    fov: float = math.pi,
    geometry: tuple[float, float, float, float] = (2.83, 0.76, 3.78, 0.5),
    sensor_offset: tuple[float, float] = (0.0, 0.0),
    max_observations: int | None = None,
) -> LandmarkSequence:
    """Simulate ``num_steps`` scans of a car lapping a circle of ``radius`` m.

    Each keyword is one knob of the world, the path, the sensor or the noise, with a
    default; tests and benchmarks change one or two at a time.

    The path is the circle through the origin centred at ``(0, radius)``; the car
    starts at the origin heading along +x (counter-clockwise laps). ``geometry`` is
    ``(L, H, A, B)`` as in :class:`jaxslam.models.vehicle.CarGeometry`.
    ``max_observations`` fixes the padded width ``Z`` (so that runs of different seeds
    share shapes and compiled code); a scan that sees more landmarks keeps the nearest.
    """
    rng = np.random.default_rng(seed)
    landmarks = _scatter_landmarks(rng, num_landmarks, radius, landmark_band, min_separation)
    centre = np.array([0.0, radius])
    pose = np.zeros(3)
    k = rows_per_step
    true_controls = np.zeros((num_steps, k, 3))
    poses = np.zeros((num_steps, 3))
    obs_lists: list[list[tuple[float, float, int]]] = []
    for t in range(num_steps):
        for j in range(k):
            # Steer towards a point a quarter-radius ahead on the circle.
            rel = pose[:2] - centre
            ang = math.atan2(rel[1], rel[0]) + 0.35
            target = centre + radius * np.array([np.cos(ang), np.sin(ang)])
            err = wrap_angle(math.atan2(target[1] - pose[1], target[0] - pose[0]) - pose[2])
            steer = float(np.clip(1.5 * err, -0.5, 0.5))
            v = speed * (1.0 + 0.2 * np.sin(0.05 * (t * k + j) * dt * 2 * np.pi))
            true_controls[t, j] = (v, steer, dt)
            pose = _move(pose, v, steer, dt, geometry)
        poses[t] = pose
        c, s = np.cos(pose[2]), np.sin(pose[2])
        sensor = pose[:2] + np.array([c * sensor_offset[0] - s * sensor_offset[1], s * sensor_offset[0] + c * sensor_offset[1]])
        d = landmarks - sensor
        r = np.hypot(d[:, 0], d[:, 1])
        b = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[2])
        seen = np.nonzero((r < max_range) & (np.abs(b) <= 0.5 * fov))[0]
        obs_lists.append(
            [
                (r[i] + range_std * rng.standard_normal(), wrap_angle(b[i] + bearing_std * rng.standard_normal()), int(i))
                for i in seen
            ]
        )
    controls = true_controls.copy()
    controls[..., 0] += speed_std * rng.standard_normal((num_steps, k))
    controls[..., 1] += steering_std * rng.standard_normal((num_steps, k))
    if max_observations is not None:
        obs_lists = [sorted(o)[:max_observations] for o in obs_lists]
        width = max_observations
    else:
        width = max(1, max(len(o) for o in obs_lists))
    observations = np.zeros((num_steps, width, 2))
    mask = np.zeros((num_steps, width), bool)
    assoc = -np.ones((num_steps, width), np.int64)
    for t, obs in enumerate(obs_lists):
        for j, (rr, bb, i) in enumerate(obs):
            observations[t, j] = (rr, bb)
            mask[t, j] = True
            assoc[t, j] = i
    times = dt * k * np.arange(1, num_steps + 1)
    meta = dict(
        dataset="landmark-sim",
        seed=seed,
        num_steps=num_steps,
        rows_per_step=k,
        dt=dt,
        speed=speed,
        radius=radius,
        num_landmarks=int(landmarks.shape[0]),
        speed_std=speed_std,
        steering_std=steering_std,
        range_std=range_std,
        bearing_std=bearing_std,
        max_range=max_range,
        fov=fov,
        geometry=tuple(geometry),
        sensor_offset=tuple(sensor_offset),
        K=k,
        Z=width,
    )
    return LandmarkSequence(
        times=times,
        controls=controls,
        observations=observations,
        obs_mask=mask,
        gps_times=times,
        gps_xy=poses[:, :2].copy(),
        true_poses=poses,
        true_controls=true_controls,
        landmarks=landmarks,
        associations=assoc,
        meta=meta,
    )
