"""Fault handling of the controller emulator: injection, latches, ClearFaults, host ids.

:class:`FaultHandling` is a mixin of
:class:`~valve_driver_pkg.emulator.controller.ControllerEmulator` (kept apart so each module
stays short); it works on the emulator's state under the emulator's lock.
"""
from __future__ import annotations

import logging
import time

from valve_driver_pkg.emulator.config import FLAG_HOLD_S
from valve_driver_pkg.protocol.codec import EmulatorFault
from valve_driver_pkg.protocol.error_frames import BusCondition, make_error_frame

__all__ = ['FaultHandling']

logger = logging.getLogger('valve_driver_pkg.emulator.controller')


class FaultHandling:
    """Injected faults, the overcurrent latch, ClearFaults and the hosts seen."""

    def inject(self, fault: EmulatorFault, active: bool = True, probability: float = 1.0,
               duration_s: float = 0.0) -> None:
        """Switch a fault on or off now (the in-process control API).

        Parameters
        ----------
        fault : EmulatorFault
            ``CLEAR_ALL`` ends every fault.
        active : bool
            False switches ``fault`` off.
        probability : float
            Per-frame probability for drop/corrupt/wrong-length/unknown-id.
        duration_s : float
            The fault ends by itself after this much model time; 0 = until cleared.
        """
        with self._lock:
            if fault is EmulatorFault.CLEAR_ALL or not active:
                ending = (list(self.faults.snapshot()) if fault is EmulatorFault.CLEAR_ALL
                          else [fault.name.lower()] if self.faults.is_active(fault) else [])
                self.faults.clear(None if fault is EmulatorFault.CLEAR_ALL else fault)
                for name in ending:
                    self._on_fault_end(EmulatorFault[name.upper()])
                return
            started = not self.faults.is_active(fault)
            self.faults.activate(fault, self._model_t, probability, duration_s)
            logger.info('emulator: fault %s on (p=%g, %s)', fault.name.lower(), probability,
                        f'{duration_s:g} s' if duration_s > 0 else 'until cleared')
            if started:
                self._on_fault_start(fault)

    def _on_fault_start(self, fault: EmulatorFault) -> None:
        if fault is EmulatorFault.BUS_OFF:
            self._send(make_error_frame(BusCondition.BUS_OFF, time.time()))
        elif fault is EmulatorFault.ERROR_PASSIVE:
            self._send(make_error_frame(BusCondition.ERROR_PASSIVE, time.time()))
        elif fault is EmulatorFault.OVERCURRENT:
            self._overcurrent = True
            self._apply_output()

    def _on_fault_end(self, fault: EmulatorFault) -> None:
        logger.info('emulator: fault %s off', fault.name.lower())
        if fault is EmulatorFault.BUS_OFF:
            self._send(make_error_frame(BusCondition.RESTARTED, time.time()))
        elif fault is EmulatorFault.ERROR_PASSIVE:
            self._send(make_error_frame(BusCondition.ERROR_ACTIVE, time.time()))

    def _note_host(self, host_id: int) -> None:
        others = [h for h, t in self.host_ids.items()
                  if h != host_id and self._model_t - t <= FLAG_HOLD_S]
        if others and host_id not in self.host_ids:
            logger.warning('emulator: commands from host %d and host(s) %s', host_id,
                           ', '.join(map(str, others)))
        self.host_ids[host_id] = self._model_t

    def overcurrent_present(self) -> bool:
        """The overcurrent condition persists (coil current above the limit, or an injected
        overcurrent whose duration is still running)."""
        injected = self.faults.snapshot().get('overcurrent')
        return (self._last_current_a > self.config.overcurrent_a
                or (injected is not None and injected.until_s is not None))

    def _clear_faults(self) -> None:
        """ClearFaults: release the latches whose condition is gone; drop the held flags."""
        self.stats['fault_clears'] += 1
        for key in self._flag_until:
            self._flag_until[key] = -1.0
        if self._overcurrent and not self.overcurrent_present():
            self._overcurrent = False
            self.faults.clear(EmulatorFault.OVERCURRENT)   # an injected one-shot event
            logger.info('emulator: overcurrent cleared')
        elif self._overcurrent:
            logger.info('emulator: overcurrent not cleared: the condition persists')
