"""Admittance control law for hand guiding: force/torque -> twist.

Per sample: bias subtraction -> low-pass (step from the samples' own stamps) -> deadband (shifted,
so motion starts smoothly at the threshold) -> gain -> axis mask -> speed limit. The speed limit
scales the whole linear (angular) vector so the direction of the push is kept. Zeroing the bias
on request averages the next few samples while commanding zero: the sensor reads its offset while
nobody touches the tool.

The wrench must be expressed in the frame the twist is commanded in; `sensor_rotation` turns the
sensor's axes into that frame (no lever-arm shift of the torque).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from servo_app.inputs.samples import Measurement, TwistSample
from servo_app.inputs.shaping import LowPass, clamp_norm, deadband

WRENCH_KEYS = ("fx", "fy", "fz", "tx", "ty", "tz")
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class AdmittanceParams:
    linear_gain: float = 2.0  # mm/s per N
    angular_gain: float = 5.0  # deg/s per N m
    force_deadband_n: float = 2.0
    torque_deadband_nm: float = 0.2
    max_linear_mm_s: float = 50.0
    max_angular_deg_s: float = 20.0
    lowpass_hz: float | None = 10.0
    axes: tuple[bool, bool, bool, bool, bool, bool] = (True, True, True, True, True, True)
    keys: tuple[str, ...] = WRENCH_KEYS  # measurement names of Fx Fy Fz Tx Ty Tz
    bias_samples: int = 10
    sensor_rotation: tuple[tuple[float, float, float], ...] | None = None  # 3x3, frame <- sensor
    frame: str = "tool"


class Admittance:
    def __init__(self, params: AdmittanceParams | None = None) -> None:
        self.p = params or AdmittanceParams()
        self.bias: tuple[float, ...] = (0.0,) * 6
        self._lp = LowPass(self.p.lowpass_hz)
        self._last_stamp: float | None = None
        self._bias_needed = 0
        self._bias_acc: list[list[float]] = []

    @property
    def biasing(self) -> bool:
        return self._bias_needed > 0

    def request_bias(self, samples: int | None = None) -> None:
        """Average the next `samples` wrenches into the bias; the output is zero until done."""
        self._bias_needed = max(1, samples or self.p.bias_samples)
        self._bias_acc = []

    def cancel_bias(self) -> None:
        """Drop a zeroing under way; the bias stays what it was."""
        self._bias_needed = 0
        self._bias_acc = []

    def reset(self) -> None:
        self._lp.reset()
        self._last_stamp = None

    def step(self, wrench: Sequence[float], stamp: float) -> tuple[Vec3, Vec3]:
        w = list(wrench)
        if len(w) != 6:
            raise ValueError(f"wrench needs 6 values, got {len(w)}")
        if self.p.sensor_rotation is not None:
            w = _rotate(self.p.sensor_rotation, w[:3]) + _rotate(self.p.sensor_rotation, w[3:])
        if self._bias_needed:
            self._bias_acc.append(w)
            if len(self._bias_acc) >= self._bias_needed:
                n = len(self._bias_acc)
                self.bias = tuple(sum(s[i] for s in self._bias_acc) / n for i in range(6))
                self._bias_needed = 0
                self.reset()
            return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
        dt = 0.0 if self._last_stamp is None else stamp - self._last_stamp
        self._last_stamp = stamp
        f = self._lp.step([w[i] - self.bias[i] for i in range(6)], dt)
        p = self.p
        v = [deadband(f[i], p.force_deadband_n) * p.linear_gain for i in range(3)]
        v += [deadband(f[i], p.torque_deadband_nm) * p.angular_gain for i in range(3, 6)]
        v = [x if on else 0.0 for x, on in zip(v, p.axes, strict=True)]
        lin = clamp_norm(v[:3], p.max_linear_mm_s)
        ang = clamp_norm(v[3:], p.max_angular_deg_s)
        return (lin[0], lin[1], lin[2]), (ang[0], ang[1], ang[2])

    def twist(self, m: Measurement, source: str = "admittance") -> TwistSample:
        """Step on a force/torque Measurement; raises KeyError naming a missing value."""
        try:
            wrench = [m.values[k] for k in self.p.keys]
        except KeyError as exc:
            raise KeyError(f"measurement from {m.source!r} has no {exc.args[0]!r}; has {sorted(m.values)}") from None
        lin, ang = self.step(wrench, m.stamp)
        return TwistSample(lin, ang, self.p.frame, m.stamp, source)


def _rotate(r: Sequence[Sequence[float]], v: Sequence[float]) -> list[float]:
    return [sum(r[i][j] * v[j] for j in range(3)) for i in range(3)]
