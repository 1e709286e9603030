"""The IMU at the seed's ``ImuALink``: MuJoCo's gyro and accelerometer, averaged over the
time since the last reading (an IMU's output filter), plus seeded noise and a constant
seeded bias (:class:`Imu`: the errors; :class:`ImuSensor`: the sensor on a body)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["IMU_PERIOD_STEPS", "STANDARD_GRAVITY", "Imu", "ImuReading", "ImuSensor"]

#: The IMU's mean is taken over every this many steps (8 ms: far above its output rate).
IMU_PERIOD_STEPS = 4
STANDARD_GRAVITY = 9.81


@dataclass(frozen=True, slots=True)
class ImuReading:
    """One IMU sample in the IMU's frame (base_link's axes): rad/s and m/s², averaged over
    the time since the previous reading, noise and bias included."""

    t: float  #: s of emulated time
    angular_velocity: tuple[float, float, float]
    linear_acceleration: tuple[float, float, float]
    #: the body's true orientation (w, x, y, z), for a consumer that wants one
    orientation: tuple[float, float, float, float]
    #: the noise's variance per axis in this reading ((rad/s)², (m/s²)²)
    angular_velocity_variance: float = 0.0
    linear_acceleration_variance: float = 0.0

    def record(self) -> dict[str, Any]:
        return {"t": self.t, "angular_velocity": list(self.angular_velocity),
                "linear_acceleration": list(self.linear_acceleration),
                "orientation": list(self.orientation),
                "angular_velocity_variance": self.angular_velocity_variance,
                "linear_acceleration_variance": self.linear_acceleration_variance}


@dataclass(frozen=True, slots=True)
class Imu:
    """The IMU's errors. The seed names no part (an ESP8266 reads "the IMU" over SPI) and
    gives no figures, only that the gyro's yaw rate is noisier than the LIDAR's and more so
    when turning faster (§3.6.2–3.6.4); these are an MPU-9250-class MEMS part's datasheet
    figures at a 50 Hz output (docs/robot.md)."""

    gyro_noise: float = math.radians(0.1)  #: rad/s, one sigma per reading
    gyro_bias: float = math.radians(0.5)  #: rad/s, one sigma of the constant bias per axis
    #: rad/s of extra noise per rad/s of yaw rate (vibration while turning, §3.6.3)
    gyro_rate_noise: float = 0.02
    accel_noise: float = 0.03  #: m/s², one sigma per reading
    accel_bias: float = 0.05  #: m/s², one sigma of the constant bias per axis


class ImuSensor:
    """The sensors' samples summed between readings (:meth:`sample`, every
    :data:`IMU_PERIOD_STEPS` steps), each reading their mean with this part's errors
    (:meth:`read`). Bias and noise come from one generator seeded by the body's seed."""

    def __init__(self, errors: Imu, seed: int) -> None:
        self.errors = errors
        self._rng = np.random.default_rng([seed, 0x1A0])
        self._gyro_bias = self._rng.normal(0.0, errors.gyro_bias, 3)
        self._accel_bias = self._rng.normal(0.0, errors.accel_bias, 3)
        self._sum = np.zeros(6)
        self._samples = 0

    def sample(self, sensordata: np.ndarray[Any, Any]) -> None:
        """The gyro's and the accelerometer's present values (MuJoCo's sensordata[:6])."""
        self._sum += sensordata[:6]
        self._samples += 1

    def mean(self) -> np.ndarray[Any, Any] | None:
        """The samples' mean since the last reading (``None``: no sample since)."""
        if not self._samples:
            return None
        mean: np.ndarray[Any, Any] = self._sum / self._samples
        return mean

    def read(self, t: float, mean: np.ndarray[Any, Any],
             orientation: tuple[float, float, float, float]) -> ImuReading:
        """A reading of ``mean`` (gyro rad/s, accelerometer m/s²) with noise and bias; the
        next reading's mean starts from here."""
        self._sum[:] = 0.0
        self._samples = 0
        errors = self.errors
        rng = self._rng
        gyro_sigma = errors.gyro_noise + errors.gyro_rate_noise * abs(float(mean[2]))
        gyro = mean[:3] + self._gyro_bias + rng.normal(0.0, gyro_sigma, 3)
        accel = mean[3:] + self._accel_bias + rng.normal(0.0, errors.accel_noise, 3)
        return ImuReading(t, (float(gyro[0]), float(gyro[1]), float(gyro[2])),
                          (float(accel[0]), float(accel[1]), float(accel[2])),
                          orientation, gyro_sigma**2, errors.accel_noise**2)
