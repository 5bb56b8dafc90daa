"""Drive electronics of the valve (paper Section 4): boost, current chopper with PI, capacitor.

The valve's internal electronics turn the main PWM input into the coil voltage:

1. **Boost.** At each rising edge of the main PWM the full supply voltage is applied until
   the valve has opened. The end of the opening is detected as real peak-and-hold drivers
   do: the controller samples the coil current once per chopper period; the spool's motion
   makes the current fall (the local peak of Fig. 4) and the end of stroke makes it rise
   again, so the boost ends at the first sample where the current rises after it has
   fallen at least ``dip_threshold_a`` below its running maximum. ``max_boost_time_s``
   bounds the boost if no dip is seen (valve blocked, supply too low); with
   ``dip_detection=False`` it is a fixed boost time.
2. **Current control.** Then a chopper at ``chopper_frequency_hz`` switches between the
   supply voltage and free-wheeling (0 V). A discrete PI controller, sampled at the start
   of each chopper period, sets the chopper duty so the current holds
   ``holding_current_a`` (0.5 A in the paper). The integrator starts at the feed-forward
   duty R I_hold / V_supply and is clamped to [0, 1] (anti-windup).
3. **Negative voltage.** A capacitor charges towards ``capacitor_voltage_v`` while the main
   PWM is high (first order, ``capacitor_charge_time_s``); at the falling edge it is
   applied reversed and discharges as a first-order low-pass with that initial value
   (``capacitor_discharge_time_s``), then 0 V. It speeds up closing.
4. **Reverse blocking.** The driver's diodes do not let the coil current reverse: when
   the (magnetising) current reaches 0 during the off phase it stays there.

Every part can be switched off; :meth:`ElectronicsConfig.off` is the bare coil, so a
bench voltage step drives the coil directly.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from .parameters import ParameterError

__all__ = ['ElectronicsConfig']

# Index layout of ElectronicsConfig.to_vector() (kernel input).
E_CURRENT_CONTROL = 0
E_HOLD_A = 1
E_CHOPPER_HZ = 2
E_KP = 3
E_KI = 4
E_DIP_DETECTION = 5
E_DIP_A = 6
E_BOOST_MAX_S = 7
E_CAPACITOR = 8
E_CAP_V = 9
E_CAP_CHARGE_S = 10
E_CAP_DISCHARGE_S = 11
E_BLOCK_REVERSE = 12
N_E = 13


@dataclasses.dataclass(frozen=True)
class ElectronicsConfig:
    """Drive electronics settings (frozen, validated).

    Attributes
    ----------
    current_control : bool
        Boost then chopper + PI holding current. False: the full supply voltage for the
        whole high phase of the main PWM.
    holding_current_a : float
        Current set point after opening, A (paper: about 0.5 A).
    chopper_frequency_hz : float
        Internal current-control PWM frequency, Hz (also the controller's sampling rate).
    kp_per_a : float
        PI proportional gain, chopper duty per A.
    ki_per_a_s : float
        PI integral gain, chopper duty per (A s).
    dip_detection : bool
        End the boost at the end-of-stroke current dip (else after ``max_boost_time_s``).
    dip_threshold_a : float
        Fall below the running maximum that counts as the opening dip, A.
    max_boost_time_s : float
        Longest boost, s.
    negative_voltage : bool
        Apply the capacitor's negative voltage at the falling edge.
    capacitor_voltage_v : float
        Voltage the capacitor charges towards while the main PWM is high, V.
    capacitor_charge_time_s : float
        Charging time constant, s.
    capacitor_discharge_time_s : float
        Time constant of the negative pulse's first-order decay, s.
    block_reverse_current : bool
        Hold the current at 0 instead of letting it reverse in the off phase.
    """

    current_control: bool = True
    holding_current_a: float = 0.5
    chopper_frequency_hz: float = 20000.0
    kp_per_a: float = 20.0
    ki_per_a_s: float = 2000.0
    dip_detection: bool = True
    dip_threshold_a: float = 0.01
    max_boost_time_s: float = 0.010
    negative_voltage: bool = True
    capacitor_voltage_v: float = 24.0
    capacitor_charge_time_s: float = 1.0e-3
    capacitor_discharge_time_s: float = 0.5e-3
    block_reverse_current: bool = True

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.type in ('bool', bool):
                if not isinstance(value, (bool, np.bool_)):
                    raise ParameterError(f'{f.name} must be a bool, got {value!r}')
                object.__setattr__(self, f.name, bool(value))
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
                raise ParameterError(f'{f.name} must be a number, got {value!r}')
            value = float(value)
            if not math.isfinite(value):
                raise ParameterError(f'{f.name} must be finite, got {value!r}')
            object.__setattr__(self, f.name, value)
        for name in ('holding_current_a', 'chopper_frequency_hz', 'capacitor_charge_time_s',
                     'capacitor_discharge_time_s'):
            if getattr(self, name) <= 0.0:
                raise ParameterError(f'{name} must be positive, got {getattr(self, name)!r}')
        for name in ('kp_per_a', 'ki_per_a_s', 'dip_threshold_a', 'max_boost_time_s',
                     'capacitor_voltage_v'):
            if getattr(self, name) < 0.0:
                raise ParameterError(
                    f'{name} must be non-negative, got {getattr(self, name)!r}')

    @classmethod
    def off(cls) -> ElectronicsConfig:
        """Bare coil: no current control, no negative voltage (a bench voltage step)."""
        return cls(current_control=False, negative_voltage=False)

    @classmethod
    def from_dict(cls, data: dict) -> ElectronicsConfig:
        """Build from a mapping of field names (unknown keys refused)."""
        names = {f.name for f in dataclasses.fields(cls)}
        for key in data:
            if key not in names:
                raise ParameterError(f'unknown electronics setting {key!r} = {data[key]!r}')
        return cls(**data)

    def to_dict(self) -> dict:
        """Return the fields as a plain dict."""
        return dataclasses.asdict(self)

    def replace(self, **changes: float | bool) -> ElectronicsConfig:
        """Return a validated copy with ``changes`` applied."""
        return dataclasses.replace(self, **changes)

    def to_vector(self) -> np.ndarray:
        """Float64 vector for the compiled kernel (layout ``E_*`` in this module)."""
        e = np.zeros(N_E)
        e[E_CURRENT_CONTROL] = float(self.current_control)
        e[E_HOLD_A] = self.holding_current_a
        e[E_CHOPPER_HZ] = self.chopper_frequency_hz
        e[E_KP] = self.kp_per_a
        e[E_KI] = self.ki_per_a_s
        e[E_DIP_DETECTION] = float(self.dip_detection)
        e[E_DIP_A] = self.dip_threshold_a
        e[E_BOOST_MAX_S] = self.max_boost_time_s
        e[E_CAPACITOR] = float(self.negative_voltage)
        e[E_CAP_V] = self.capacitor_voltage_v
        e[E_CAP_CHARGE_S] = self.capacitor_charge_time_s
        e[E_CAP_DISCHARGE_S] = self.capacitor_discharge_time_s
        e[E_BLOCK_REVERSE] = float(self.block_reverse_current)
        return e
