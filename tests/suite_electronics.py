"""Drive electronics descriptions (the suite's YAML) of the test-data generator's forms."""
from __future__ import annotations

__all__ = ['TIMER_HYSTERESIS_ZENER_YAML']

# The generator's timer_hysteresis_zener form (tests/datagen/electronics.py) written as the
# suite's description: a 5 ms timer, a 0.55 A +- 30 mA band clocked at 40 kHz with diode
# free-wheeling, a 36 V Zener.
TIMER_HYSTERESIS_ZENER_YAML = """\
electronics:
  peak_end: timer
  max_boost_time_s: 0.005
  hold: hysteresis
  holding_current_a: 0.55
  hysteresis_band_a: 0.06
  comparator_frequency_hz: 40000.0
  hold_decay: diode
  diode_drop_v: 0.7
  release: zener
  zener_voltage_v: 36.0
"""
