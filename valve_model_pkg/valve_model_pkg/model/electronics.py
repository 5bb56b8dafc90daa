"""Drive electronics of the valve (paper Section 4) as a family of peak-and-hold drivers.

The electronics turn the main PWM input into the coil terminal voltage. Real
peak-and-hold drivers differ in how they end the peak phase, how they hold the current
and how they release the valve; each of these is a choice with its constants in
:class:`ElectronicsConfig`. ``ElectronicsConfig()`` is the paper's driver (dip-ended
boost, PI chopper with free-wheeling, capacitor pulse, reverse current blocked);
:meth:`ElectronicsConfig.off` is the bare coil (a bench voltage step).

1. **Peak phase** (``peak_end``). At each rising edge of the main PWM the full supply
   voltage is applied. It ends:

   * ``'dip'``: at the first controller sample (once per chopper period, aligned with the
     rising edge) where the current rises above the previous sample after it has fallen
     at least ``dip_threshold_a`` below its running maximum: the current dip of the
     end of stroke (the local peak of Fig. 4, then the rise);
   * ``'dip_rise'``: after such a dip, at the first sample where the current is at least
     ``rise_threshold_a`` above its running minimum since the dip;
   * ``'threshold'``: the instant the current reaches ``peak_current_a`` (a comparator;
     the integrator lands on the crossing);
   * ``'timer'``: exactly ``max_boost_time_s`` after the rising edge.

   ``max_boost_time_s`` bounds the peak phase of the other forms too (valve blocked,
   supply too low): the dip forms check it at their samples, the threshold form ends
   exactly then.
2. **Hold** (``hold``), from the end of the peak phase until the falling edge:

   * ``'pi'``: a chopper at ``chopper_frequency_hz`` whose duty a discrete PI controller
     (``kp_per_a``, ``ki_per_a_s``, sampled at each chopper period start) sets so the
     current holds ``holding_current_a``; its integrator starts at the feed-forward duty
     R I_hold / V_supply and is clamped to [0, 1] (anti-windup);
   * ``'hysteresis'``: a comparator sampled at ``comparator_frequency_hz`` switches the
     supply on below ``holding_current_a - hysteresis_band_a / 2`` and off above
     ``holding_current_a + hysteresis_band_a / 2``;
   * ``'pwm'``: open loop, the supply chopped at ``chopper_frequency_hz`` with the fixed
     duty ``hold_duty`` (a reduced mean voltage V_supply * hold_duty).

   While the chopper is off the coil sees ``hold_decay``: ``'freewheel'`` (0 V, slow
   decay through a switch), ``'diode'`` (-``diode_drop_v`` through a free-wheel diode,
   slow decay) or ``'fast'`` (-V_supply through the bridge, fast decay).
3. **Release** (``release``), at the falling edge, when ``negative_voltage`` is on (else
   0 V):

   * ``'capacitor'``: a capacitor charged towards ``capacitor_voltage_v`` (first order,
     ``capacitor_charge_time_s``) while the main PWM is high is applied reversed and
     decays as a first-order low-pass (``capacitor_discharge_time_s``), then 0 V;
   * ``'capacitor_peak'``: the same pulse from a capacitor charged only during the peak
     phase (the whole high phase without current control);
   * ``'zener'``: a Zener clamp, -``zener_voltage_v`` until the current reaches zero;
   * ``'diode'``: a free-wheel diode, -``diode_drop_v`` until the current reaches zero.
4. **Reverse current.** With ``block_reverse_current`` the driver's diodes do not let the
   coil current reverse under the capacitor pulse or fast decay: the (magnetising)
   current stops at zero. The diode and Zener paths conduct one way by construction: their
   current always ends at zero, then the coil sees 0 V.

``current_control`` switches the peak and hold phases (False: the full supply for the
whole high phase); ``negative_voltage`` switches the release (False: 0 V, free-wheeling).
A description file (YAML, :meth:`ElectronicsConfig.from_yaml`, :func:`load_electronics`)
holds the same fields; examples are in ``config/electronics/``.
"""
from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from .parameters import ParameterError, _one_line, _yaml_document

__all__ = ['ElectronicsConfig', 'HOLD_DECAYS', 'HOLD_FORMS', 'PEAK_ENDS', 'RELEASES',
           'load_electronics']

#: Ways the peak phase ends (``peak_end``), in kernel code order.
PEAK_ENDS = ('timer', 'dip', 'dip_rise', 'threshold')
#: Hold forms (``hold``), in kernel code order.
HOLD_FORMS = ('pi', 'hysteresis', 'pwm')
#: Coil voltage while the hold's chopper is off (``hold_decay``), in kernel code order.
HOLD_DECAYS = ('freewheel', 'diode', 'fast')
#: Release forms (``release``), in kernel code order.
RELEASES = ('capacitor', 'capacitor_peak', 'zener', 'diode')

# Kernel codes of the forms (their index in the tuples above).
PEAK_TIMER, PEAK_DIP, PEAK_DIP_RISE, PEAK_THRESHOLD = 0, 1, 2, 3
HOLD_PI, HOLD_HYSTERESIS, HOLD_PWM = 0, 1, 2
DECAY_FREEWHEEL, DECAY_DIODE, DECAY_FAST = 0, 1, 2
RELEASE_CAPACITOR, RELEASE_CAPACITOR_PEAK, RELEASE_ZENER, RELEASE_DIODE = 0, 1, 2, 3

# Index layout of ElectronicsConfig.to_vector() (kernel input).
E_CURRENT_CONTROL = 0
E_HOLD_A = 1
E_CHOPPER_HZ = 2
E_KP = 3
E_KI = 4
E_PEAK_END = 5
E_DIP_A = 6
E_BOOST_MAX_S = 7
E_CAPACITOR = 8      # negative_voltage: the release is on
E_CAP_V = 9
E_CAP_CHARGE_S = 10
E_CAP_DISCHARGE_S = 11
E_BLOCK_REVERSE = 12
E_RISE_A = 13
E_PEAK_A = 14
E_HOLD = 15
E_BAND_A = 16
E_COMPARATOR_HZ = 17
E_HOLD_DUTY = 18
E_DECAY = 19
E_DIODE_V = 20
E_RELEASE = 21
E_ZENER_V = 22
N_E = 23

_CHOICES = {'peak_end': PEAK_ENDS, 'hold': HOLD_FORMS, 'hold_decay': HOLD_DECAYS,
            'release': RELEASES}
_POSITIVE = ('holding_current_a', 'chopper_frequency_hz', 'capacitor_charge_time_s',
             'capacitor_discharge_time_s', 'peak_current_a', 'comparator_frequency_hz',
             'zener_voltage_v')
_NON_NEGATIVE = ('kp_per_a', 'ki_per_a_s', 'dip_threshold_a', 'rise_threshold_a',
                 'max_boost_time_s', 'capacitor_voltage_v', 'hysteresis_band_a',
                 'diode_drop_v')


@dataclasses.dataclass(frozen=True)
class ElectronicsConfig:
    """Drive electronics: the form of each phase and its constants (frozen, validated).

    The module docstring describes each form; docs/model.md gives the coil voltage of
    each phase.

    Attributes
    ----------
    current_control : bool
        Peak and hold phases. False: the full supply voltage for the whole high phase.
    peak_end : {'dip', 'dip_rise', 'threshold', 'timer'}
        How the peak phase ends.
    dip_threshold_a : float
        Fall below the running maximum that counts as the end-of-stroke dip, A.
    rise_threshold_a : float
        ``'dip_rise'``: rise above the running minimum after the dip that ends the peak, A.
    peak_current_a : float
        ``'threshold'``: current that ends the peak phase, A.
    max_boost_time_s : float
        Longest peak phase, s (the time of ``'timer'``).
    hold : {'pi', 'hysteresis', 'pwm'}
        How the current is held after the peak phase.
    holding_current_a : float
        Hold set point (``'pi'``, ``'hysteresis'``), A (paper: about 0.5 A).
    chopper_frequency_hz : float
        Chopper frequency of ``'pi'`` and ``'pwm'``, Hz; also the rate at which the dip
        forms sample the current.
    kp_per_a : float
        PI proportional gain, chopper duty per A.
    ki_per_a_s : float
        PI integral gain, chopper duty per (A s).
    hysteresis_band_a : float
        Width of the hysteresis band around ``holding_current_a``, A.
    comparator_frequency_hz : float
        Clock at which the hysteresis comparator samples the current, Hz.
    hold_duty : float
        Fixed chopper duty of ``'pwm'`` in [0, 1].
    hold_decay : {'freewheel', 'diode', 'fast'}
        Coil voltage while the chopper is off: 0 V, -``diode_drop_v``, -V_supply.
    diode_drop_v : float
        Forward drop of the free-wheel diode (``hold_decay='diode'``, ``release='diode'``), V.
    negative_voltage : bool
        Release through ``release`` at the falling edge (False: 0 V).
    release : {'capacitor', 'capacitor_peak', 'zener', 'diode'}
        How the coil is released at the falling edge.
    capacitor_voltage_v : float
        Voltage the capacitor charges towards, V.
    capacitor_charge_time_s : float
        Charging time constant, s.
    capacitor_discharge_time_s : float
        Time constant of the negative pulse's first-order decay, s.
    zener_voltage_v : float
        Clamp voltage of ``release='zener'``, V.
    block_reverse_current : bool
        Stop the current at zero instead of letting it reverse under the capacitor pulse
        or fast decay.
    """

    current_control: bool = True
    peak_end: str = 'dip'
    dip_threshold_a: float = 0.01
    rise_threshold_a: float = 0.01
    peak_current_a: float = 1.0
    max_boost_time_s: float = 0.010
    hold: str = 'pi'
    holding_current_a: float = 0.5
    chopper_frequency_hz: float = 20000.0
    kp_per_a: float = 20.0
    ki_per_a_s: float = 2000.0
    hysteresis_band_a: float = 0.05
    comparator_frequency_hz: float = 100000.0
    hold_duty: float = 0.3
    hold_decay: str = 'freewheel'
    diode_drop_v: float = 0.7
    negative_voltage: bool = True
    release: str = 'capacitor'
    capacitor_voltage_v: float = 24.0
    capacitor_charge_time_s: float = 1.0e-3
    capacitor_discharge_time_s: float = 0.5e-3
    zener_voltage_v: float = 30.0
    block_reverse_current: bool = True

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, _checked(f.name, f.type, getattr(self, f.name)))
        for name in _POSITIVE:
            if getattr(self, name) <= 0.0:
                raise ParameterError(f'{name} must be positive, got {getattr(self, name)!r}',
                                     key=name)
        for name in _NON_NEGATIVE:
            if getattr(self, name) < 0.0:
                raise ParameterError(
                    f'{name} must be non-negative, got {getattr(self, name)!r}', key=name)
        if self.hold_duty > 1.0:
            raise ParameterError(f'hold_duty must be in [0, 1], got {self.hold_duty!r}',
                                 key='hold_duty')

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
                raise ParameterError(f'unknown electronics setting {key!r} = {data[key]!r} '
                                     f'(known: {", ".join(sorted(names))})', key=str(key))
        return cls(**data)

    @classmethod
    def from_yaml(cls, path: str | os.PathLike[str]) -> ElectronicsConfig:
        """Read a description file (see :func:`load_electronics`)."""
        return load_electronics(path)

    def to_dict(self) -> dict:
        """Return the fields as a plain dict."""
        return dataclasses.asdict(self)

    def to_yaml(self, path: str | os.PathLike[str] | None = None) -> str:
        """The description file of this configuration (all fields, in groups); written to
        ``path`` if given. :func:`load_electronics` reads it back to an equal config."""
        lines = ['electronics:']
        for title, names in _YAML_GROUPS:
            lines.append(f'  # {title}')
            for name in names:
                lines.append(f'  {name}: {_yaml_value(getattr(self, name))}')
        text = '\n'.join(lines) + '\n'
        if path is not None:
            Path(path).write_text(text, encoding='utf-8')
        return text

    def replace(self, **changes: float | bool | str) -> ElectronicsConfig:
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
        e[E_PEAK_END] = PEAK_ENDS.index(self.peak_end)
        e[E_DIP_A] = self.dip_threshold_a
        e[E_BOOST_MAX_S] = self.max_boost_time_s
        e[E_CAPACITOR] = float(self.negative_voltage)
        e[E_CAP_V] = self.capacitor_voltage_v
        e[E_CAP_CHARGE_S] = self.capacitor_charge_time_s
        e[E_CAP_DISCHARGE_S] = self.capacitor_discharge_time_s
        e[E_BLOCK_REVERSE] = float(self.block_reverse_current)
        e[E_RISE_A] = self.rise_threshold_a
        e[E_PEAK_A] = self.peak_current_a
        e[E_HOLD] = HOLD_FORMS.index(self.hold)
        e[E_BAND_A] = self.hysteresis_band_a
        e[E_COMPARATOR_HZ] = self.comparator_frequency_hz
        e[E_HOLD_DUTY] = self.hold_duty
        e[E_DECAY] = HOLD_DECAYS.index(self.hold_decay)
        e[E_DIODE_V] = self.diode_drop_v
        e[E_RELEASE] = RELEASES.index(self.release)
        e[E_ZENER_V] = self.zener_voltage_v
        return e


def _checked(name: str, kind: object, value: object) -> bool | str | float:
    """``value`` of field ``name`` as its type (bool, a form name or a finite float)."""
    if kind in ('bool', bool):
        if not isinstance(value, (bool, np.bool_)):
            raise ParameterError(f'{name} must be true or false, got {value!r}', key=name)
        return bool(value)
    if name in _CHOICES:
        if not isinstance(value, str) or value not in _CHOICES[name]:
            raise ParameterError(f'{name} must be one of {", ".join(_CHOICES[name])}, got '
                                 f'{value!r}', key=name)
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
        raise ParameterError(f'{name} must be a number, got {value!r}', key=name)
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f'{name} must be finite, got {value!r}', key=name)
    return value


_YAML_GROUPS = (
    ('peak phase', ('current_control', 'peak_end', 'dip_threshold_a', 'rise_threshold_a',
                    'peak_current_a', 'max_boost_time_s')),
    ('hold', ('hold', 'holding_current_a', 'chopper_frequency_hz', 'kp_per_a', 'ki_per_a_s',
              'hysteresis_band_a', 'comparator_frequency_hz', 'hold_duty', 'hold_decay',
              'diode_drop_v')),
    ('release', ('negative_voltage', 'release', 'capacitor_voltage_v',
                 'capacitor_charge_time_s', 'capacitor_discharge_time_s', 'zener_voltage_v',
                 'block_reverse_current')),
)


def _yaml_value(value: bool | str | float) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return value
    return repr(value)  # the shortest text that reads back to the same float


def load_electronics(path: str | os.PathLike[str]) -> ElectronicsConfig:
    """Read a drive electronics description file (YAML).

    The file holds the fields of :class:`ElectronicsConfig` as top-level keys, or under a
    single top-level key ``electronics:``; a field not given keeps its default (the
    paper's driver). Numbers are read as YAML 1.2 does (``20e3`` is a float).

    Parameters
    ----------
    path : path-like
        The YAML file.

    Returns
    -------
    ElectronicsConfig

    Raises
    ------
    ParameterError
        One line naming the file, the line and the key with its value: the file is
        binary, not UTF-8, too large, not valid YAML, not a mapping, has a duplicate or an
        unknown key, or a value of the wrong type or out of range.
    FileNotFoundError
        If the file does not exist.
    """
    path = Path(path)
    data, lines = _yaml_document(path, 'an electronics file')
    if data is None:
        data = {}
    if isinstance(data, dict) and 'electronics' in data:
        if len(data) != 1:
            other = next(k for k in data if k != 'electronics')
            raise ParameterError(f'{path}:{lines.get(other, "?")}: unknown key {other!r} '
                                 'beside the electronics: block (a description file holds '
                                 'only the electronics)')
        data = data['electronics'] if data['electronics'] is not None else {}
    if not isinstance(data, dict):
        raise ParameterError(f'{path}: an electronics file is a mapping of settings (or an '
                             f'electronics: block), got {type(data).__name__}')
    try:
        return ElectronicsConfig.from_dict(data)
    except ParameterError as err:
        line = lines.get(err.key) if err.key is not None else None
        where = f'{path}:{line}' if line else str(path)
        raise ParameterError(f'{where}: {_one_line(err)}', key=err.key) from err
    except TypeError as err:  # a non-string key
        raise ParameterError(f'{path}: {_one_line(err)}') from err
